"""``magwarp train``: train a policy on a magwarp env with PPO or SAC + HER, within a wall-clock budget.

Runs the CleanRL-style scripts ``examples/train_ppo.py`` / ``examples/train_sac_her.py`` (a checkout's examples
folder) with a progress bar (steps/s, current success rate). Writes under ``--out``: ``policy.pt`` (TorchScript, for
``magwarp eval`` and ``magwarp export``), ``checkpoint.pt`` (``--resume``), ``progress.csv`` and ``curve.png``.

    magwarp train magwarp/TrajectoryPlanningB0-v0 --algo ppo --minutes 15 --out runs/b0_ppo
    magwarp train magwarp/PushBox-v0 --algo sac-her --minutes 15 --out runs/pushbox
    magwarp train magwarp/PushBox-v0 --algo sac-her --resume runs/pushbox --minutes 5
    magwarp train magwarp/PushT-v0 --algo sac-her --minutes 15 --args "--batch-size 16384 --updates-per-step 4"

Hyper-parameters default to the script's preset for the task family; ``--args`` passes any other script option.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from magwarp.commands import CommandError, UsageError, add_trust_option, loading_errors

HELP = "train a policy on an env (PPO or SAC + HER) within a wall-clock budget"
SCRIPTS = {"ppo": "train_ppo.py", "sac-her": "train_sac_her.py"}


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("train", help=HELP, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("env_id", metavar="ENV_ID", nargs="?", default=None,
                   help="env id, e.g. magwarp/TrajectoryPlanningB0-v0 (optional with --resume)")
    p.add_argument("--algo", choices=sorted(SCRIPTS), default=None, help="ppo or sac-her (default: ppo, or the "
                   "checkpoint's algorithm with --resume)")
    p.add_argument("--num-envs", type=int, default=None, help="parallel worlds (default: the algorithm's preset)")
    p.add_argument("--minutes", type=float, default=None, help="wall-clock training budget (default 15)")
    p.add_argument("--total-steps", type=float, default=None, help="also stop after this many env steps")
    p.add_argument("--device", default=None, help="cpu or cuda[:N] (default: cuda when available)")
    p.add_argument("--out", default=None, help="run folder (default: runs/<env>_<algo>)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--resume", default=None, help="run folder or checkpoint.pt to continue")
    p.add_argument("--env-kwargs", default=None, help='JSON env options, e.g. \'{"num_movers": 2}\'')
    p.add_argument("--args", dest="script_args", default="", help="more options for the training script, quoted")
    p.add_argument("--tensorboard", action="store_true", help="also log TensorBoard scalars to OUT/tb")
    add_trust_option(p)
    return p


def script_path(algo: str) -> Path:
    import magwarp

    path = Path(magwarp.__file__).resolve().parent.parent / "examples" / SCRIPTS[algo]
    if not path.is_file():
        raise CommandError(f"the training scripts live in the repository's examples/ folder ({path} is missing): "
                           "run magwarp train from a source checkout (pip install -e .)")
    return path


def load_script(algo: str):
    import importlib.util

    path = script_path(algo)
    spec = importlib.util.spec_from_file_location(f"magwarp_train_{algo.replace('-', '_')}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def build_argv(args) -> list[str]:
    argv: list[str] = []
    for flag, value in (("--env-id", args.env_id), ("--num-envs", args.num_envs), ("--minutes", args.minutes),
                        ("--total-steps", args.total_steps), ("--device", args.device), ("--out", args.out),
                        ("--seed", args.seed), ("--resume", args.resume), ("--env-kwargs", args.env_kwargs)):
        if value is not None:
            argv += [flag, str(value)]
    if args.tensorboard:
        argv.append("--tensorboard")
    try:
        argv += shlex.split(args.script_args or "")
    except ValueError as e:
        raise UsageError(f"--args {args.script_args!r}: {e}") from None
    return argv


def resume_algo(resume: str, *, trusted: bool = False) -> str | None:
    """The algorithm a ``--resume`` checkpoint was trained with; checks that it is a readable magwarp checkpoint
    (loaded without running pickled code unless ``trusted``; the training script then loads it the same way)."""
    import os

    from magwarp.training.common import checkpoint_path, load_checkpoint, trust_checkpoints

    ckpt_path = checkpoint_path(resume)
    if not os.path.isfile(ckpt_path):
        raise UsageError(f"--resume: no checkpoint at {ckpt_path!r}")
    trust_checkpoints(trusted)
    with loading_errors():
        state = load_checkpoint(ckpt_path, "cpu")
    missing = [k for k in ("args",) if not isinstance(state.get(k), dict)]
    if missing:
        raise UsageError(f"--resume: {ckpt_path!r} is not a magwarp training checkpoint (no {missing[0]!r} entry)")
    return state.get("algo")


def run(args) -> int:
    if args.env_id is None and args.resume is None:
        raise UsageError("give an ENV_ID (or --resume RUN_FOLDER)")
    if args.num_envs is not None and args.num_envs < 1:
        raise UsageError(f"--num-envs must be >= 1, got {args.num_envs}")
    if args.minutes is not None and not args.minutes > 0:
        raise UsageError(f"--minutes must be positive, got {args.minutes}")
    if args.env_id is not None:
        import gymnasium as gym

        import magwarp  # noqa: F401 - registers the ids

        if args.env_id not in gym.registry or not args.env_id.startswith("magwarp/"):
            raise UsageError(f"unknown env id {args.env_id!r} (try magwarp/TrajectoryPlanningB0-v0, magwarp/PushBox-v0,"
                             " magwarp/PushT-v0, magwarp/PushWithObstacles-v0)")
    algo = args.algo
    if args.resume is not None:
        saved = resume_algo(args.resume, trusted=args.trust)
        if algo is not None and saved is not None and algo != saved:
            raise UsageError(f"--algo {algo} but the checkpoint {ckpt_path!r} was trained with {saved}")
        algo = algo or saved
    algo = algo or "ppo"
    if args.minutes is None and args.total_steps is None and args.resume is None:
        args.minutes = 15.0
    module = load_script(algo)
    try:
        script_args = module.parse_args(build_argv(args))
    except SystemExit as e:  # argparse error inside --args
        raise UsageError(f"bad training option in {build_argv(args)} (see python {script_path(algo)} --help)") from e
    if script_args.minutes is None and script_args.total_steps is None and args.resume is not None:
        script_args.minutes = 15.0
    summary = module.train(script_args)
    print(f"magwarp train: {algo} done: success rate {summary['success_rate']:.3f} after "
          f"{summary['global_step']:,} env steps, {summary['wall_s']:.0f} s")
    return 0
