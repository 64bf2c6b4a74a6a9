"""``magwarp bench``: run the benchmark scripts of ``benchmarks/`` with small defaults; print their tables and
optionally write PNG plots and JSON rows (with device, date, versions and command in every row).

    magwarp bench                                  # all three, small sizes, Warp's default device(s)
    magwarp bench scaling --device cpu --plot      # paper's scalability test -> ./bench_scaling.png
    magwarp bench env --json out/ --plot out/      # env-steps/s against num_envs -> out/bench_env.{json,png}
    magwarp bench render --steps 20 --json         # top-down renderer frames/s -> ./bench_render.json
    magwarp bench scaling --full --magbotsim       # the script's own (paper-sized) defaults, MagBotSim beside
    magwarp bench env -- --num-envs 1,4096 --envs magwarp/PushT-v0    # after --: the script's own options

Kinds: ``scaling`` (benchmarks/scaling.py), ``env`` (benchmarks/env_throughput.py), ``render``
(benchmarks/render_fps.py). The scripts live in a source checkout (``benchmarks/`` beside the package, or the folder
in ``MAGWARP_BENCHMARKS``); options after ``--`` go to the script unchanged (see ``python benchmarks/<script> -h``).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import os
import sys
from pathlib import Path

from magwarp.commands import CommandError, UsageError

HELP = "benchmarks: simulator scaling, env throughput, renderer fps; tables, PNG plots, JSON"
SCRIPTS = {"scaling": "scaling.py", "env": "env_throughput.py", "render": "render_fps.py"}
KINDS = tuple(SCRIPTS)

# Small sizes: a minute or so per kind on a laptop CPU. --full drops them (the scripts' defaults are paper-sized).
SMALL_DEFAULTS = {
    "scaling": ["--max-movers", "200", "--steps", "50", "--skip-large", "--ref-steps", "20",
                "--max-controller-movers", "100"],
    "env": ["--envs", "magwarp/TrajectoryPlanningB0-v0,magwarp/PushBox-v0", "--num-envs", "1,64,1024",
            "--push-num-envs", "1,16", "--steps", "20", "--adapters-at", "64", "--magbotsim-steps", "50"],
    "render": ["--worlds", "1", "16", "64", "--px-per-tile", "16", "24", "32", "--frames", "20", "--repeats", "3"],
}
STEPS_OPTION = {"scaling": "--steps", "env": "--steps", "render": "--frames"}
NO_MAGBOTSIM = {"scaling": ["--no-magbotsim"], "env": ["--no-magbotsim"], "render": []}


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("bench", help=HELP, description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("kind", nargs="?", default="all", choices=KINDS + ("all",),
                   help="which benchmark (default: all three)")
    p.add_argument("--device", default=None,
                   help="cpu or cuda:N (default: the script's: cpu, plus cuda:0 when present)")
    p.add_argument("--steps", type=int, default=None,
                   help="timed steps per configuration (render: frames per repeat)")
    p.add_argument("--full", action="store_true",
                   help="the scripts' own defaults (paper-sized; long) instead of small ones")
    p.add_argument("--magbotsim", action="store_true",
                   help="also time MagBotSim in the same run (scaling, env; needs `pip install magbotsim`; slow)")
    p.add_argument("--plot", nargs="?", const=".", default=None, metavar="PATH",
                   help="write PNG plots: a .png file (one kind) or a folder for bench_<kind>.png (default: .)")
    p.add_argument("--json", nargs="?", const=".", default=None, metavar="PATH",
                   help="write the rows as JSON: a .json file (one kind) or a folder for bench_<kind>.json "
                        "(default: .)")
    p.set_defaults(script_args=[])
    p.usage = f"{p.prog} [{{{','.join(KINDS + ('all',))}}}] [options] [-- SCRIPT_OPTIONS]"
    _split_at_double_dash(p)
    return p


def _split_at_double_dash(parser: argparse.ArgumentParser) -> None:
    """Everything after ``--`` goes to the script (``args.script_args``), whatever it looks like. (argparse's
    REMAINDER would also swallow our own options after the optional KIND positional.)"""
    original = parser.parse_known_args

    def parse_known_args(args=None, namespace=None):
        args = list(sys.argv[1:] if args is None else args)
        tail: list[str] = []
        if "--" in args:
            i = args.index("--")
            args, tail = args[:i], args[i + 1:]
        ns, extra = original(args, namespace)
        ns.script_args = tail
        return ns, extra

    parser.parse_known_args = parse_known_args


def benchmarks_dir() -> Path:
    """The folder holding the benchmark scripts: ``$MAGWARP_BENCHMARKS`` or ``benchmarks/`` of the checkout."""
    env = os.environ.get("MAGWARP_BENCHMARKS")
    folder = Path(env) if env else Path(__file__).resolve().parents[2] / "benchmarks"
    if not (folder / SCRIPTS["scaling"]).is_file():
        raise CommandError(f"benchmark scripts not found in {folder}: magwarp bench runs the scripts of a source "
                           "checkout (git clone, pip install -e .) or of the folder named by MAGWARP_BENCHMARKS")
    return folder


def load_script(kind: str):
    """Import ``benchmarks/<script>`` by path (once per process) and return the module (its ``main(argv)`` runs it)."""
    folder = benchmarks_dir()
    path = folder / SCRIPTS[kind]
    name = f"magwarp_bench_{path.stem}"
    if name in sys.modules:
        return sys.modules[name]
    if str(folder) not in sys.path:  # the scripts import their shared helpers (common.py, magbotsim_ref.py)
        sys.path.insert(0, str(folder))
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def _output(path: str | None, kind: str, ext: str, several: bool) -> str | None:
    if path is None:
        return None
    if path.lower().endswith(ext):
        if several:
            raise UsageError(f"{path!r} names one file, but several benchmarks run: give a folder instead")
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder):
            raise UsageError(f"output {path!r}: folder {folder} does not exist")
        return path
    if os.path.exists(path) and not os.path.isdir(path):
        raise UsageError(f"output {path!r} exists and is not a folder; give a folder or a *{ext} file")
    os.makedirs(path, exist_ok=True)
    return os.path.join(path, f"bench_{kind}{ext}")


def script_argv(args, kind: str, several: bool) -> tuple[list[str], dict[str, str | None]]:
    """The script's argv (small defaults, then our options, then the user's pass-through ones) and output files."""
    argv = [] if args.full else list(SMALL_DEFAULTS[kind])
    if not args.magbotsim:
        argv += NO_MAGBOTSIM[kind]
    if args.device:
        argv += ["--device", args.device]
    if args.steps is not None:
        argv += [STEPS_OPTION[kind], str(args.steps)]
    outputs = {"plot": _output(args.plot, kind, ".png", several), "json": _output(args.json, kind, ".json", several)}
    for opt, path in outputs.items():
        if path:
            argv += [f"--{opt}", path]
    return argv + list(args.script_args), outputs


@contextlib.contextmanager
def _one_line_argparse_errors(script: str):
    """The scripts' argparse errors as one-line UsageErrors (not a usage block and SystemExit)."""
    original = argparse.ArgumentParser.error

    def error(self, message):
        raise UsageError(f"benchmarks/{script}: {message} (see 'python benchmarks/{script} -h')")

    argparse.ArgumentParser.error = error
    try:
        yield
    finally:
        argparse.ArgumentParser.error = original


def run(args) -> int:
    if args.steps is not None and args.steps < 1:
        raise UsageError(f"--steps must be >= 1, got {args.steps}")
    for opt in ("plot", "json"):  # `magwarp bench --plot env`: argparse took the kind for --plot's path
        value = getattr(args, opt)
        if args.kind == "all" and value in KINDS and not os.path.isdir(value):
            args.kind = value
            setattr(args, opt, ".")
    kinds = KINDS if args.kind == "all" else (args.kind,)
    several = len(kinds) > 1
    if several and args.script_args:
        raise UsageError("options after -- go to one script: name the benchmark (scaling, env or render)")
    plans = [(kind, *script_argv(args, kind, several)) for kind in kinds]
    import torch

    threads = torch.get_num_threads()  # the scripts pin torch to one thread; give the caller its setting back
    try:
        for kind, argv, outputs in plans:
            script = SCRIPTS[kind]
            print(f"== magwarp bench {kind}: python benchmarks/{script} {' '.join(argv)}", flush=True)
            module = load_script(kind)
            with _one_line_argparse_errors(script):
                rc = module.main(argv)
            if rc:
                raise CommandError(f"benchmarks/{script} exited with code {rc}")
            written = [p for p in outputs.values() if p and os.path.exists(p)]
            if written:
                print(f"== wrote {', '.join(written)}", flush=True)
    finally:
        torch.set_num_threads(threads)
    return 0
