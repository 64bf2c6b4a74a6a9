"""``magwarp view``: run an env (or a synthetic scene) and show it live in 3D through Newton's viewers.

    magwarp view --synthetic --worlds 4 --viewer usd -o run.usda      # file for Omniverse / Isaac / usdview
    magwarp view --synthetic --viewer viser                          # browser at http://127.0.0.1:8080
    magwarp view magwarp/PushT-v0 --viewer gl                        # OpenGL window (needs a display)
    magwarp view magwarp/PushBox-v0 --worlds 4 --viewer usd -o push.usda   # object, goal, obstacles too
    magwarp view magwarp/Swarm-v0 --num-movers 10000                 # one big world, top-down, live
    magwarp view magwarp/Swarm-v0 --num-movers 10000 --window 12,12,6 --steps 250 -o swarm.mp4
    magwarp view magwarp/Levitation-v0 --viewer coils -o coils.mp4     # coil currents (the PD baseline flies)

TOP-DOWN (--viewer topdown, the default for swarm envs): one big world drawn by the swarm renderer (movers coloured
by state; a --window of it zoomed) in a window where a display exists, else written to -o (default
magwarp_view.mp4; .gif too). --live window / video forces one.

COILS (--viewer coils): the coil currents of an env with the magnetic model (magwarp/Levitation-v0 and its
variants, or any env built with force_model="magnetic" through --env-kwargs) from above, one panel per coil layer,
coloured by current with a colour bar, the movers outlined on top (magwarp.render.coils); to a window or a video as
for topdown.

The browser viewer binds to 127.0.0.1 unless --host says otherwise.
"""

from __future__ import annotations

import argparse
import json
import time

from magwarp.commands import CommandError, UsageError
from magwarp.commands.render import add_common_scene_args, check_scene_args, env_policy, make_env, make_synthetic, shown_worlds

HELP = "live 3D viewer through Newton: GL window, browser (viser), USD file, Rerun"
VIEWERS = ("gl", "viser", "usd", "rerun", "null", "topdown", "coils")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("view", help=HELP, description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_common_scene_args(p)
    p.set_defaults(steps=None)
    p.add_argument("--viewer", choices=VIEWERS, default=None,
                   help="backend (default: topdown for swarm envs, else gl)")
    p.add_argument("--num-movers", type=int, default=None, help="swarm envs: movers in the world")
    p.add_argument("--env-kwargs", default=None, metavar="JSON", help="env options (SwarmConfig fields for swarms)")
    p.add_argument("--window", default=None, metavar="CX,CY,W[,H]", help="topdown: draw only this window (metres)")
    p.add_argument("--max-px", type=int, default=1024, help="topdown: longest image side (default 1024)")
    p.add_argument("--live", choices=("auto", "window", "video"), default="auto",
                   help="topdown: a window where a display exists, else a video file (default auto)")
    p.add_argument("-o", "--out", default=None, metavar="PATH", help="output file: .usd/.usda (usd), .rrd (rerun)")
    p.add_argument("--host", default="127.0.0.1", help="viser: address to bind (default 127.0.0.1, this machine only)")
    p.add_argument("--port", type=int, default=8080, help="viser: port (default 8080)")
    p.add_argument("--fps", type=float, default=25.0, help="frames per second (playback rate; live pacing)")
    p.add_argument("--realtime", action="store_true", help="live viewers: pace frames at --fps")
    return p


def _topdown(args, coils: bool = False) -> int:
    """One world (or --show of them) top-down through the swarm renderer (``coils``: the env's coil currents), live
    in a window or to a video."""
    from tqdm import tqdm

    from magwarp.commands.render import parse_window
    from magwarp.record import as_frame
    from magwarp.render.live import LiveView

    if args.synthetic:
        raise UsageError(f"--viewer {args.viewer} shows an env (e.g. magwarp/Swarm-v0), not --synthetic")
    window = parse_window(args.window)
    env = make_env(args, render_mode="rgb_array")
    base = env.unwrapped if hasattr(env, "unwrapped") else env
    if hasattr(base, "set_render_worlds"):
        base.set_render_worlds(shown_worlds(args))
    render = env.render
    if coils:
        if window is not None:
            raise UsageError("--window applies to --viewer topdown, not coils")
        if getattr(base, "coil_source", lambda: None)() is None:
            raise UsageError(f"env {args.env_id!r} has no magnetic model, so no coil currents: use a "
                             f"magwarp/Levitation-v0 env or --env-kwargs '{{\"force_model\": \"magnetic\"}}'")
        render = base.render_coils
    elif hasattr(base, "set_render_view"):
        try:
            base.set_render_view(window=window, max_image_px=args.max_px)
        except ValueError as e:
            raise UsageError(str(e)) from None
    elif window is not None:
        raise UsageError(f"--window applies to swarm envs (e.g. magwarp/Swarm-v0), not {args.env_id}")
    out = args.out or "magwarp_view.mp4"
    if args.live != "window" and not out.lower().endswith((".mp4", ".gif")):
        raise UsageError(f"--viewer topdown writes .mp4 or .gif without a display, got {out!r}")
    try:
        live = LiveView(args.live, path=out, fps=args.fps, title=args.env_id or "magwarp")
    except (RuntimeError, ValueError) as e:  # e.g. no ffmpeg for mp4, or --live window without a display
        raise CommandError(str(e)) from e
    except Exception as e:  # Tk's TclError: no display
        raise CommandError(f"cannot open a window ({e}); use --live video -o FILE.mp4") from e
    policy = env_policy(env, args.policy)
    obs = env.reset(seed=args.seed)[0]
    period = 1.0 / args.fps
    try:
        for _ in tqdm(range(args.steps), desc="view", unit="step", disable=None, leave=False):
            t0 = time.perf_counter()
            obs = env.step(policy(obs))[0]
            live.show(as_frame(render()))
            if not live.running:
                break
            if args.realtime:
                time.sleep(max(0.0, period - (time.perf_counter() - t0)))
    finally:
        target = live.close()
    if target != "window":
        print(f"wrote {target} ({live.frames} frames)")
    return 0


def run(args) -> int:
    if args.num_movers is not None:
        if args.num_movers < 1:
            raise UsageError(f"--num-movers must be >= 1, got {args.num_movers}")
        try:
            options = json.loads(args.env_kwargs) if args.env_kwargs else {}
        except ValueError as e:
            raise UsageError(f"--env-kwargs must be a JSON object: {e}") from None
        if not isinstance(options, dict):
            raise UsageError(f"--env-kwargs must be a JSON object, got {args.env_kwargs!r}")
        args.env_kwargs = json.dumps({**options, "num_movers": args.num_movers})
    if args.viewer is None:
        args.viewer = "topdown" if args.env_id and "swarm" in args.env_id.lower() else "gl"
    if args.viewer in ("topdown", "coils"):
        if args.steps is None:  # a file gets a short clip; a window runs until closed (or 10 000 steps)
            args.steps = 10_000 if args.live == "window" else 100
        check_scene_args(args)
        return _topdown(args, coils=args.viewer == "coils")
    if args.window is not None:
        raise UsageError("--window applies to --viewer topdown")
    if args.steps is None:  # files get a short clip; live viewers run until closed (or 10 000 steps)
        args.steps = 100 if args.viewer in ("usd", "null") else 10_000
    check_scene_args(args)
    if args.viewer == "usd":
        if not args.out:
            raise UsageError("--viewer usd needs -o FILE.usda (or .usd/.usdc)")
        if not args.out.lower().endswith((".usd", ".usda", ".usdc")):
            raise UsageError(f"USD output must end in .usd, .usda or .usdc, got {args.out!r}")
    if args.fps <= 0:
        raise UsageError(f"--fps must be > 0, got {args.fps}")
    from tqdm import tqdm

    from magwarp.viewer import SceneViewer, make_viewer

    show = shown_worlds(args)
    try:
        viewer = make_viewer(args.viewer, path=args.out, host=args.host, port=args.port, fps=args.fps,
                             num_frames=args.steps if args.viewer in ("usd", "null") else None)
    except RuntimeError as e:  # e.g. no display for the OpenGL window
        raise CommandError(str(e)) from e
    if args.synthetic:
        scene = make_synthetic(args)
        shapes = [scene.object_shape] if scene.objects else None
        sv = SceneViewer(viewer, scene.layout, scene.mover, worlds=show, object_shapes=shapes, fps=args.fps)

        def step():
            scene.step()
            a = scene.arrays()
            sv.log(a["pos"], a["quat"], flags=a["collision"], goals=a["goals"], object_poses=a.get("object_poses"),
                   object_goals=a.get("object_goals"), obstacles=a.get("obstacles"))
    else:
        env = make_env(args, render_mode=None)
        base = env.unwrapped if hasattr(env, "unwrapped") else env
        sim = getattr(base, "sim", None)
        push = hasattr(base, "render_state")  # push envs (mujoco-warp): object, its goal, obstacles
        if sim is None and not push:
            raise UsageError(f"env {args.env_id!r} does not expose .sim; the viewer needs the simulator's state arrays")
        policy = env_policy(env, args.policy)
        if push:
            sv = SceneViewer(viewer, base.layout, base.mover, worlds=show, object_shapes=[base.object_parts()],
                             fps=args.fps)
        else:
            sv = SceneViewer(viewer, sim.layout, sim.mover, worlds=show, fps=args.fps)
        state = {"obs": env.reset(seed=args.seed)[0]}

        def step():
            state["obs"] = env.step(policy(state["obs"]))[0]
            if push:
                s = base.render_state()
                sv.log(s["pos"], s["yaw"], flags=s["flags"], object_poses=s["object_poses"],
                       object_goals=s["object_goals"], obstacles=s.get("obstacles"))
                return
            flags = getattr(sim, "flags_any", None)  # collisions during the whole env step, not only its last cycle
            if flags is None:
                flags = getattr(sim, "flags", None)
            sv.log(sim.pos, sim.quat, flags=flags, radii=getattr(sim, "radii", None),
                   half_sizes=getattr(sim, "half_sizes", None), goals=getattr(base, "goals", None))

    if args.viewer == "viser":
        print(f"viewer at http://{args.host}:{args.port} (Ctrl-C to stop)")
    period = 1.0 / args.fps
    try:
        for _ in tqdm(range(args.steps), desc="view", unit="step", disable=None, leave=False):
            t0 = time.perf_counter()
            step()
            if not sv.is_running():
                break
            if args.realtime:
                time.sleep(max(0.0, period - (time.perf_counter() - t0)))
    finally:
        sv.close()
    if args.out:
        print(f"wrote {args.out} ({sv.frame} frames, {show} of {args.worlds} worlds)")
    return 0
