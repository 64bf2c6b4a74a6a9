"""Subcommands of the ``magwarp`` command, one module each.

A subcommand module ``magwarp/commands/<name>.py`` defines:

* ``add_parser(subparsers) -> argparse.ArgumentParser``: add ``<name>`` with its options (keep imports light here:
  ``magwarp --help`` and ``magwarp <name> --help`` must stay fast, so import torch/warp/newton inside ``run``);
* ``run(args) -> int``: do the work and return the exit code.

User mistakes (bad names, paths, sizes) should raise :class:`UsageError` (or a ``ValueError``/``LayoutError`` with a
clear message): the CLI prints them as one line on stderr and exits with code 2, without a traceback. Problems of the
machine rather than the call (no display for a window, a missing optional package) raise :class:`CommandError`
(one line, exit code 1).
"""

from __future__ import annotations

import contextlib

__all__ = ["UsageError", "CommandError", "SUBCOMMANDS", "add_trust_option", "loading_errors"]


class UsageError(ValueError):
    """A mistake in how the command was called; reported as one line, exit code 2."""


class CommandError(RuntimeError):
    """Something this machine cannot do (no display, missing optional package); reported as one line, exit code 1."""


def add_trust_option(parser) -> None:
    """``--trust``: load policy/checkpoint files that hold pickled Python objects (see :mod:`magwarp._io`)."""
    parser.add_argument("--trust", action="store_true",
                        help="load a policy or checkpoint file that holds pickled Python objects (e.g. a whole "
                             "torch.save'd module): unpickling can run any code, so only for files you trust")


@contextlib.contextmanager
def loading_errors():
    """Report files that cannot or may not be loaded (corrupt, or pickled code without --trust) as usage errors."""
    from magwarp._io import UnreadableFileError

    try:
        yield
    except UnreadableFileError as e:
        raise UsageError(str(e)) from None


# Known subcommands and their one-line help, listed here so ``magwarp --help`` needs no imports. A module present in
# this package but missing from this table is still found (by name), with a generic help line.
SUBCOMMANDS = {
    "demo": "run the built-in planner on a big batch on the best device; print throughput, write a video and a PNG",
    "bench": "benchmarks: simulator and env throughput, scaling plots",
    "eval": "evaluate a policy on an env: success rate, collisions, makespan, ...",
    "render": "render steps of an env (or a synthetic scene) top-down to PNG, gif or mp4",
    "view": "live 3D viewer through Newton: GL window, browser (viser), USD file, Rerun",
    "train": "train a policy on an env (PPO or SAC + HER)",
    "export": "export a trained policy as ONNX",
}
