"""``magwarp render``: run an env (or a synthetic scene) for some steps and write top-down images or a video.

    magwarp render --synthetic --layout B1 --worlds 4 --steps 60 -o run.gif -o last.png
    magwarp render magwarp/TrajectoryPlanning-v0 --worlds 16 --steps 100 --policy random -o tp.mp4
    magwarp render magwarp/Swarm-v0 --env-kwargs '{"num_movers": 1000}' --steps 50 -o swarm.gif -o swarm.png
    magwarp render magwarp/Swarm-v0 --env-kwargs '{"num_movers": 1000}' --window 3,3,2 --px-per-tile 48 -o zoom.png

Outputs by extension: ``.png`` (the last frame), ``.gif`` / ``.mp4`` (every frame). Several ``-o`` are allowed.

BIG SWARMS (magwarp/Swarm-v0, magwarp/SwarmMaterialFlow-v0): the whole world fits --max-px (default 1024 pixels on
the longest side); movers are coloured by state (moving, idle, collided, carrying a job, waiting to respawn) and
stay at least 2 x 2 pixels however many there are. ``--window CX,CY,W[,H]`` (metres; a tile is 0.24 m) draws only
that part, at full detail.
"""

from __future__ import annotations

import argparse
import os

from magwarp.commands import CommandError, UsageError

HELP = "render steps of an env (or a synthetic scene) top-down to PNG, gif or mp4"
POLICIES = ("scripted", "random", "zero")


def add_common_scene_args(p: argparse.ArgumentParser) -> None:
    """Options shared by ``render`` and ``view``: which scene, how many worlds and steps, which policy."""
    p.add_argument("env_id", nargs="?", default=None, metavar="ENV_ID",
                   help="gymnasium env id, e.g. magwarp/TrajectoryPlanning-v0 (omit with --synthetic)")
    p.add_argument("--synthetic", action="store_true",
                   help="no simulator: movers glide to random goals (for trying the renderer/viewer)")
    p.add_argument("--layout", default="B0", help="synthetic scene: benchmark layout B0..B9 (default B0)")
    p.add_argument("--movers", type=int, default=None, help="synthetic scene: movers per world (default: layout's)")
    p.add_argument("--objects", action="store_true", help="synthetic scene: add a T object, its goal and 2 obstacles")
    p.add_argument("--worlds", type=int, default=1, help="worlds to simulate (default 1)")
    p.add_argument("--show", type=int, default=None, metavar="N", help="worlds to draw (default: all, at most 64)")
    p.add_argument("--steps", type=int, default=50, help="steps to run (default 50)")
    p.add_argument("--policy", choices=POLICIES, default=None,
                   help="env actions: the env's scripted planner, random or zero (default: scripted where the env "
                        "has a planner, else random)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--device", default=None, help="Warp device, e.g. cpu or cuda:0 (default: Warp's preferred)")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("render", help=HELP, description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_common_scene_args(p)
    p.add_argument("-o", "--out", action="append", default=None, metavar="PATH",
                   help="output .png (last frame), .gif or .mp4; repeat for several (default: magwarp_render.gif)")
    p.add_argument("--fps", type=float, default=25.0, help="video frame rate (default 25: one frame per env step)")
    p.add_argument("--px-per-tile", type=int, default=None, help="resolution (default: 64 for one world, less for more)")
    p.add_argument("--scale", type=int, default=1, help="integer upscaling of the written images (default 1)")
    p.add_argument("--legend", action=argparse.BooleanOptionalAction, default=True,
                   help="colour key under the images (default on)")
    p.add_argument("--window", default=None, metavar="CX,CY,W[,H]",
                   help="swarm envs: draw only this window (metres: centre x, y, width, height; default: the world)")
    p.add_argument("--max-px", type=int, default=1024,
                   help="swarm envs: longest image side when --px-per-tile is not given (default 1024)")
    p.add_argument("--env-kwargs", default=None, metavar="JSON",
                   help="env options, e.g. '{\"num_movers\": 1000}' (swarm envs: SwarmConfig fields)")
    p.add_argument("--3d", dest="three_d", action="store_true",
                   help="push envs: 3D images through MuJoCo's offscreen renderer (EGL/OSMesa) instead of top-down")
    return p


def check_scene_args(args) -> None:
    if args.env_id is None and not args.synthetic:
        raise UsageError("give an ENV_ID, or --synthetic for a scene without the simulator")
    if args.env_id is not None and args.synthetic:
        raise UsageError("give either an ENV_ID or --synthetic, not both")
    for name in ("worlds", "steps"):
        if getattr(args, name) < 1:
            raise UsageError(f"--{name} must be >= 1, got {getattr(args, name)}")
    if args.show is not None and not 1 <= args.show <= args.worlds:
        raise UsageError(f"--show must be between 1 and --worlds ({args.worlds}), got {args.show}")
    if args.synthetic and args.policy not in (None, "scripted"):
        raise UsageError("a --synthetic scene moves by its own script; --policy applies to envs")


def shown_worlds(args) -> int:
    return args.show if args.show is not None else min(args.worlds, 64)


def default_px_per_tile(num_shown: int) -> int:
    return 64 if num_shown == 1 else 40 if num_shown <= 4 else 24 if num_shown <= 16 else 16


def make_synthetic(args):
    """The synthetic scene of the parsed args (layout name checked with a clear error)."""
    from magwarp.layout import benchmark_layout
    from magwarp.render import SyntheticScene

    layout, movers = benchmark_layout(args.layout)
    movers = args.movers if args.movers is not None else movers
    if movers < 1:
        raise UsageError(f"--movers must be >= 1, got {movers}")
    import warp as wp

    device = wp.device_to_torch(wp.get_device(args.device))
    return SyntheticScene(layout, num_worlds=args.worlds, num_movers=movers, seed=args.seed, objects=args.objects,
                          device=device)


def parse_window(text: str | None) -> tuple[float, float, float, float] | None:
    """``--window CX,CY,W[,H]`` (metres) -> (cx, cy, width, height); a square when H is left out."""
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (3, 4):
        raise UsageError(f"--window must be CX,CY,W or CX,CY,W,H in metres, got {text!r}")
    return tuple(values) if len(values) == 4 else (*values, values[2])


def make_env(args, render_mode: str | None = "rgb_array"):
    """A gymnasium vector env of the magwarp suite, with a clear error while the env is not available."""
    try:
        import gymnasium as gym
    except ImportError as e:
        raise ImportError("envs need gymnasium: pip install gymnasium") from e
    try:
        import magwarp.envs  # noqa: F401 - registers the magwarp/... ids
    except ImportError:
        pass
    kwargs = {"render_mode": render_mode} if render_mode else {}
    if args.device:
        kwargs["device"] = args.device
    options = {}
    if getattr(args, "env_kwargs", None):
        from magwarp.training.common import parse_env_kwargs

        try:
            options = parse_env_kwargs(args.env_kwargs)
        except ValueError as e:
            raise UsageError(str(e)) from None
    try:
        return gym.make_vec(args.env_id, num_envs=args.worlds, **kwargs, **options)
    except gym.error.Error as e:
        raise UsageError(f"cannot make env {args.env_id!r}: {e}") from e
    except (TypeError, ValueError) as e:
        if not options:
            raise
        raise UsageError(f"--env-kwargs {args.env_kwargs} for {args.env_id}: {e}") from None


def env_policy(env, name: str):
    """A function obs -> actions for a vector env: the env's scripted planner, random or zero actions
    (``None``: the planner where the env has one, else random)."""
    base = env.unwrapped if hasattr(env, "unwrapped") else env
    factory = getattr(base, "scripted_policy", None)
    if factory is None:
        from magwarp.envs.levitation import LevitationEnv

        if isinstance(base, LevitationEnv):  # its baseline lives in magwarp.policies (a PD law)
            from magwarp.policies.levitation import LevitationPD

            factory = lambda: LevitationPD(base)  # noqa: E731
    if name is None:
        name = "scripted" if factory is not None else "random"
    if name == "scripted":
        if factory is None:
            raise UsageError("this env has no scripted planner; use --policy random or --policy zero")
        return factory()  # env.scripted_policy() builds the planner: action = planner(obs)
    space = env.action_space
    if name == "random":
        return lambda obs: space.sample()
    import numpy as np

    return lambda obs: np.zeros(space.shape, dtype=space.dtype)


def check_outputs(paths: list[str]) -> list[str]:
    from magwarp.record import VIDEO_FORMATS

    for path in paths:
        ext = os.path.splitext(path)[1].lower()
        if ext not in (".png",) + VIDEO_FORMATS:
            raise UsageError(f"output {path!r}: use a .png, .gif or .mp4 file name")
        parent = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(parent):
            raise UsageError(f"output {path!r}: folder {parent} does not exist")
    return paths


def run(args) -> int:
    check_scene_args(args)
    outputs = check_outputs(args.out or ["magwarp_render.gif"])
    if args.scale < 1:
        raise UsageError(f"--scale must be >= 1, got {args.scale}")
    if args.fps <= 0:
        raise UsageError(f"--fps must be > 0, got {args.fps}")
    from tqdm import tqdm

    from magwarp.record import VideoRecorder
    from magwarp.render import save_png, to_numpy_image

    if args.three_d and args.synthetic:
        raise UsageError("--3d renders the MuJoCo scene of a push env (e.g. magwarp/PushT-v0), not --synthetic")
    show = shown_worlds(args)
    ppt = args.px_per_tile or default_px_per_tile(show)
    if ppt < 1:
        raise UsageError(f"--px-per-tile must be >= 1, got {ppt}")
    if args.synthetic:
        scene = make_synthetic(args)
        renderer = scene.make_renderer(worlds=show, px_per_tile=ppt)

        def step():
            scene.step()

        def frame():
            return scene.draw(renderer)
    else:
        window = parse_window(args.window)
        env = make_env(args, render_mode="rgb_array_3d" if args.three_d else "rgb_array")
        base = env.unwrapped if hasattr(env, "unwrapped") else env
        if args.three_d:
            from magwarp.render.mujoco3d import GLUnavailableError, gl_backend

            try:
                gl_backend()
            except GLUnavailableError as e:
                raise CommandError(str(e)) from e
        if hasattr(base, "set_render_worlds"):
            base.set_render_worlds(show)
        if hasattr(base, "set_render_view"):  # big swarms: resolution, window and state colours
            try:
                base.set_render_view(window=window, px_per_tile=args.px_per_tile, max_image_px=args.max_px)
            except ValueError as e:
                raise UsageError(str(e)) from None
        elif window is not None:
            raise UsageError(f"--window applies to swarm envs (e.g. magwarp/Swarm-v0), not {args.env_id}")
        policy = env_policy(env, args.policy)
        obs, _ = env.reset(seed=args.seed)
        state = {"obs": obs}

        def step():
            state["obs"] = env.step(policy(state["obs"]))[0]

        def frame():
            from magwarp.record import as_frame

            return as_frame(env.render())

    if args.synthetic:
        has_objects, has_obstacles = scene.objects, scene.objects
    else:
        has_objects = getattr(base, "object_poses", None) is not None or hasattr(base, "object_parts")
        has_obstacles = bool(getattr(base, "obstacles", None))
    strip = None

    def annotated(image):
        nonlocal strip
        if not args.legend or args.three_d:  # the key describes the top-down colours
            return image
        from magwarp.render.legend import legend_strip, with_legend

        image = to_numpy_image(image)
        if strip is None:
            strip = legend_strip(image.shape[1], objects=has_objects, obstacles=has_obstacles,
                                 states=None if args.synthetic else getattr(base, "render_states", None))
        return with_legend(image, strip)

    videos = [VideoRecorder(p, args.fps, scale=args.scale) for p in outputs if not p.lower().endswith(".png")]
    last = None
    try:
        for _ in tqdm(range(args.steps), desc="render", unit="step", disable=None, leave=False):
            step()
            last = annotated(frame())
            for v in videos:
                v.add(last)
    finally:
        for v in videos:
            if v.num_frames:
                v.close()
    for p in outputs:
        if p.lower().endswith(".png"):
            save_png(p, last, scale=args.scale)
    h, w = to_numpy_image(last).shape[:2]
    print(f"wrote {', '.join(outputs)} ({args.steps} steps, {show} of {args.worlds} worlds, {h * args.scale}x{w * args.scale} px)")
    return 0
