"""``magwarp train``: train a policy on a magwarp env with PPO or SAC + HER, within a wall-clock budget.

Runs the CleanRL-style modules :mod:`magwarp.training.ppo` / :mod:`magwarp.training.sac_her` with a progress bar
(steps/s, current success rate). Writes under ``--out``: ``policy.pt`` (TorchScript, for ``magwarp eval`` and
``magwarp export``), ``checkpoint.pt`` (``--resume``), ``progress.csv``, ``curve.png`` and ``run.json``.

Time to target: every ``--eval-every`` seconds (default 10) a deterministic evaluation on a separate env; the first
one whose success rate reaches ``--target`` (default: the paper's figure for the task, e.g. 0.99 for B0 and
Push-Box, 0.73 Push-T, 0.91 PushWithObstacles) is printed, with the seconds since the process started, and written
to ``OUT/run.json`` (``summary.time_to_target_s``).

Several GPUs (or CPU processes): ``--nproc-per-node N`` launches N ranks through torchrun (``--num-envs`` worlds
each, gradients averaged; see :mod:`magwarp.training.distributed`).

    magwarp train magwarp/TrajectoryPlanningB0-v0 --algo ppo --minutes 15 --out runs/b0_ppo
    magwarp train magwarp/PushBox-v0 --algo sac-her --minutes 15 --out runs/pushbox
    magwarp train magwarp/PushBox-v0 --algo sac-her --resume runs/pushbox --minutes 5
    magwarp train magwarp/PushT-v0 --algo sac-her --minutes 15 --args "--batch-size 16384 --updates-per-step 4"
    magwarp train magwarp/PushBox-v0 --algo sac-her --minutes 3 --target 0.99 --stop-at-target
    magwarp train magwarp/TrajectoryPlanningB0-v0 --minutes 5 --nproc-per-node 4

Hyper-parameters default to the module's preset for the task family; ``--args`` passes any other module option
(``python -m magwarp.training.ppo --help``).
"""

from __future__ import annotations

import argparse
import shlex

from magwarp.commands import CommandError, UsageError, add_trust_option, loading_errors

HELP = "train a policy on an env (PPO or SAC + HER) within a wall-clock budget"
MODULES = {"ppo": "magwarp.training.ppo", "sac-her": "magwarp.training.sac_her"}


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("train", help=HELP, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("env_id", metavar="ENV_ID", nargs="?", default=None,
                   help="env id, e.g. magwarp/TrajectoryPlanningB0-v0 (optional with --resume)")
    p.add_argument("--algo", choices=sorted(MODULES), default=None, help="ppo or sac-her (default: ppo, or the "
                   "checkpoint's algorithm with --resume)")
    p.add_argument("--num-envs", type=int, default=None, help="parallel worlds (default: the algorithm's preset)")
    p.add_argument("--minutes", type=float, default=None, help="wall-clock training budget (default 15)")
    p.add_argument("--total-steps", type=float, default=None, help="also stop after this many env steps")
    p.add_argument("--device", default=None, help="cpu or cuda[:N] (default: cuda when available)")
    p.add_argument("--out", default=None, help="run folder (default: runs/<env>_<algo>)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--resume", default=None, help="run folder or checkpoint.pt to continue")
    p.add_argument("--env-kwargs", default=None, help='JSON env options, e.g. \'{"num_movers": 2}\'')
    p.add_argument("--target", type=float, default=None,
                   help="success rate whose first crossing is the time to target (default: the paper's, per task)")
    p.add_argument("--stop-at-target", action="store_true", help="stop training once the target is reached")
    p.add_argument("--args", dest="script_args", default="", help="more options for the training module, quoted")
    p.add_argument("--tensorboard", action="store_true", help="also log TensorBoard scalars to OUT/tb")
    p.add_argument("--nproc-per-node", type=int, default=None, metavar="N",
                   help="train with N processes (one per GPU, or CPU processes with gloo) through torchrun")
    p.add_argument("--torchrun-args", default="", help="more torchrun options, quoted (e.g. '--nnodes 2 "
                   "--node-rank 0 --rdzv-endpoint host:29400' for several machines)")
    add_trust_option(p)
    return p


def load_module(algo: str):
    import importlib

    return importlib.import_module(MODULES[algo])


def build_argv(args) -> list[str]:
    argv: list[str] = []
    for flag, value in (("--env-id", args.env_id), ("--num-envs", args.num_envs), ("--minutes", args.minutes),
                        ("--total-steps", args.total_steps), ("--device", args.device), ("--out", args.out),
                        ("--seed", args.seed), ("--resume", args.resume), ("--env-kwargs", args.env_kwargs),
                        ("--target", args.target)):
        if value is not None:
            argv += [flag, str(value)]
    for flag, on in (("--tensorboard", args.tensorboard), ("--stop-at-target", args.stop_at_target)):
        if on:
            argv.append(flag)
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
            raise UsageError(f"--algo {algo} but the checkpoint in {args.resume!r} was trained with {saved}")
        algo = algo or saved
    algo = algo or "ppo"
    if args.minutes is None and args.total_steps is None and args.resume is None:
        args.minutes = 15.0
    module = load_module(algo)
    argv = build_argv(args)
    try:
        script_args = module.parse_args(argv)
    except SystemExit as e:  # argparse error inside --args
        raise UsageError(f"bad training option in {argv} (see python -m {MODULES[algo]} --help)") from e
    if script_args.minutes is None and script_args.total_steps is None and args.resume is not None:
        script_args.minutes = 15.0
        argv += ["--minutes", "15"]
    if args.nproc_per_node is not None:
        return _launch(args, algo, argv)
    summary = module.train(script_args)
    ttt = summary.get("time_to_target_s")
    target = "" if summary.get("target") is None else (
        f"; time to target {summary['target']:g}: " + ("not reached" if ttt is None else f"{ttt:.1f} s"))
    print(f"magwarp train: {algo} done: success rate {summary['success_rate']:.3f} after "
          f"{summary['global_step']:,} env steps, {summary['wall_s']:.0f} s{target}")
    return 0


def _launch(args, algo: str, argv: list[str]) -> int:
    """``--nproc-per-node N``: the same module under torchrun; a failed rank's exit code is the command's."""
    from magwarp.training import distributed

    if args.nproc_per_node < 1:
        raise UsageError(f"--nproc-per-node must be >= 1, got {args.nproc_per_node}")
    try:
        extra = shlex.split(args.torchrun_args or "")
    except ValueError as e:
        raise UsageError(f"--torchrun-args {args.torchrun_args!r}: {e}") from None
    rc = distributed.launch(args.nproc_per_node, MODULES[algo], argv, extra)
    if rc != 0:
        raise CommandError(f"torchrun exited with code {rc} (a rank failed: its error is above); continue from the "
                           f"last checkpoint with: magwarp train --resume {args.out or 'RUN_FOLDER'} "
                           f"--nproc-per-node {args.nproc_per_node}")
    print(f"magwarp train: {algo} done on {args.nproc_per_node} processes")
    return 0
