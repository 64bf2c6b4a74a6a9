"""``magwarp view``: run an env (or a synthetic scene) and show it live in 3D through Newton's viewers.

    magwarp view --synthetic --worlds 4 --viewer usd -o run.usda      # file for Omniverse / Isaac / usdview
    magwarp view --synthetic --viewer viser                          # browser at http://127.0.0.1:8080
    magwarp view magwarp/PushT-v0 --viewer gl                        # OpenGL window (needs a display)
    magwarp view magwarp/PushBox-v0 --worlds 4 --viewer usd -o push.usda   # object, goal, obstacles too

The browser viewer binds to 127.0.0.1 unless --host says otherwise.
"""

from __future__ import annotations

import argparse
import time

from magwarp.commands import CommandError, UsageError
from magwarp.commands.render import add_common_scene_args, check_scene_args, env_policy, make_env, make_synthetic, shown_worlds

HELP = "live 3D viewer through Newton: GL window, browser (viser), USD file, Rerun"
VIEWERS = ("gl", "viser", "usd", "rerun", "null")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("view", help=HELP, description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_common_scene_args(p)
    p.set_defaults(steps=None)
    p.add_argument("--viewer", choices=VIEWERS, default="gl", help="backend (default gl)")
    p.add_argument("-o", "--out", default=None, metavar="PATH", help="output file: .usd/.usda (usd), .rrd (rerun)")
    p.add_argument("--host", default="127.0.0.1", help="viser: address to bind (default 127.0.0.1, this machine only)")
    p.add_argument("--port", type=int, default=8080, help="viser: port (default 8080)")
    p.add_argument("--fps", type=float, default=25.0, help="frames per second (playback rate; live pacing)")
    p.add_argument("--realtime", action="store_true", help="live viewers: pace frames at --fps")
    return p


def run(args) -> int:
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
