"""torch.distributed for training and evaluation: one process per GPU (or CPU process), launched by ``torchrun``.

    torchrun --standalone --nproc-per-node 4 -m magwarp.training.ppo --env-id magwarp/TrajectoryPlanningB0-v0 ...
    magwarp train magwarp/PushBox-v0 --algo sac-her --nproc-per-node 4 ...     # the same, through the CLI

Each rank (``RANK`` of ``WORLD_SIZE``, set by torchrun) runs its own ``--num-envs`` worlds on ``cuda:LOCAL_RANK``
(NCCL between GPUs) or on the CPU (gloo), with the seed ``seed + rank``. Rank 0's initial weights are broadcast;
gradients are averaged over the ranks before every optimiser step (one all-reduce of the flattened gradients), and
the observation normaliser's batch moments and the success and episode counters are summed over the ranks, so every
rank holds the same parameters after every update. Control decisions that depend on the clock (stop, log,
checkpoint, evaluate, the learning-rate schedule) are rank 0's, broadcast to all. Rank 0 alone logs, checkpoints and
writes the policy. Every collective has a timeout (``--dist-timeout``): a rank that dies or hangs ends the job with
an error instead of a hang (torchrun also stops the job as soon as a rank exits with an error).

Without torchrun (no ``WORLD_SIZE`` in the environment) every function here is a no-op: one process, as before.
"""

from __future__ import annotations

import os
import subprocess
import sys
from datetime import timedelta
from typing import Iterable

import torch

__all__ = ["launched", "is_active", "rank", "world_size", "local_rank", "is_main", "rank_seed", "setup", "shutdown",
           "leave", "all_reduce_sum_", "average_gradients", "broadcast_", "check_in_sync", "agree", "gather_objects",
           "torchrun_command", "launch"]

_OWNED = False  # this module initialised the process group (and destroys it)


def launched() -> bool:
    """True in a process started by torchrun (``WORLD_SIZE`` and ``RANK`` are set)."""
    return "WORLD_SIZE" in os.environ and "RANK" in os.environ


def is_active() -> bool:
    return torch.distributed.is_available() and torch.distributed.is_initialized()


def rank() -> int:
    return torch.distributed.get_rank() if is_active() else 0


def world_size() -> int:
    return torch.distributed.get_world_size() if is_active() else 1


def local_rank() -> int:
    return int(os.environ.get("LOCAL_RANK", 0))


def is_main() -> bool:
    return rank() == 0


def rank_seed(seed: int) -> int:
    """This rank's seed: ``seed + rank`` (rank 0 and a single process use ``seed``)."""
    return int(seed) + rank()


def setup(device: str | None, timeout_s: float = 300.0) -> str | None:
    """Under torchrun: initialise the process group and return this rank's device; otherwise return ``device``.

    A CUDA device (``cuda``, ``cuda:N`` or None with a GPU present) becomes ``cuda:LOCAL_RANK`` with NCCL; ``cpu``
    uses gloo. torch's and Warp's current devices are set to it (Warp's default would be ``cuda:0``)."""
    global _OWNED
    if not launched():
        return device
    if timeout_s is None or not timeout_s > 0:
        raise ValueError(f"--dist-timeout must be a positive number of seconds, got {timeout_s!r}")
    use_cuda = (device is None and torch.cuda.is_available()) or str(device).startswith("cuda")
    if use_cuda:
        if not torch.cuda.is_available():
            raise ValueError(f"device {device!r} under torchrun, but CUDA is not available (use --device cpu)")
        lr = local_rank()
        if lr >= torch.cuda.device_count():
            raise ValueError(f"LOCAL_RANK {lr} but only {torch.cuda.device_count()} CUDA devices are visible")
        device = f"cuda:{lr}"
        torch.cuda.set_device(lr)
        import warp as wp

        wp.set_device(device)
    else:
        device = "cpu"
    if not is_active():
        torch.distributed.init_process_group("nccl" if use_cuda else "gloo",
                                             timeout=timedelta(seconds=float(timeout_s)),
                                             device_id=torch.device(device) if use_cuda else None)
        _OWNED = True
    return device


def shutdown(wait: bool = True) -> None:
    """Destroy the process group this module created (end of a torchrun job). ``wait``: first wait for every rank
    (rank 0 still writes its files while the others are done); off on an error, where another rank may be gone."""
    global _OWNED
    if _OWNED and is_active():
        if wait and world_size() > 1:
            torch.distributed.barrier()
        torch.distributed.destroy_process_group()
    _OWNED = False


def leave(code: int = 0) -> None:
    """End a torchrun rank's process now, after its work and :func:`shutdown`: flush stdout and stderr and
    ``os._exit``. This skips the C++ runtime's exit-time destructors, which now and then abort a finished rank
    (SIGABRT, "terminate called without an active exception": seen in 2 of 10 two-rank gloo runs here, torch 2.13),
    and torchrun would report a finished job as failed. No-op outside torchrun."""
    if not launched():
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def all_reduce_sum_(t: torch.Tensor) -> torch.Tensor:
    """Sum ``t`` over the ranks, in place (no-op in one process)."""
    if is_active() and world_size() > 1:
        torch.distributed.all_reduce(t, op=torch.distributed.ReduceOp.SUM)
    return t


def average_gradients(params: Iterable[torch.nn.Parameter]) -> None:
    """Replace every gradient by its mean over the ranks (one all-reduce of the flattened gradients)."""
    if not is_active() or world_size() == 1:
        return
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return
    flat = torch.cat([g.reshape(-1) for g in grads])
    torch.distributed.all_reduce(flat, op=torch.distributed.ReduceOp.SUM)
    flat.div_(world_size())
    offset = 0
    for g in grads:
        g.copy_(flat[offset:offset + g.numel()].view_as(g))
        offset += g.numel()


@torch.no_grad()
def broadcast_(tensors: Iterable[torch.Tensor]) -> None:
    """Rank 0's values of ``tensors`` (parameters, buffers) on every rank."""
    if not is_active() or world_size() == 1:
        return
    for t in tensors:
        torch.distributed.broadcast(t.data, src=0)


@torch.no_grad()
def check_in_sync(tensors: Iterable[torch.Tensor], what: str = "parameters") -> None:
    """Raise on every rank if some rank holds other values of ``tensors`` than rank 0 (a fingerprint of them is
    all-gathered: their sum and a position-weighted sum, in float64). Called at every checkpoint, so a run that
    diverged stops instead of training on."""
    if not is_active() or world_size() == 1:
        return
    flat = torch.cat([t.detach().reshape(-1).to(torch.float64) for t in tensors])
    weights = torch.arange(1, flat.numel() + 1, device=flat.device, dtype=torch.float64).remainder_(97.0)
    mine = torch.stack([flat.sum(), (flat * weights).sum()])
    every = [torch.zeros_like(mine) for _ in range(world_size())]
    torch.distributed.all_gather(every, mine)
    bad = [r for r, f in enumerate(every) if not torch.equal(f, every[0])]
    if bad:
        raise RuntimeError(f"ranks {bad} hold other {what} than rank 0 (fingerprints {[f.tolist() for f in every]}): "
                           "the ranks diverged")


def agree(*values: float) -> tuple:
    """Rank 0's ``values`` (flags or numbers: stop, log, checkpoint, a schedule's fraction) on every rank, with the
    types given (a bool stays a bool). One small broadcast; returns the values unchanged in one process."""
    if not is_active() or world_size() == 1:
        return values
    dev = "cuda" if torch.distributed.get_backend() == "nccl" else "cpu"
    t = torch.tensor([float(v) for v in values], dtype=torch.float64, device=dev)
    torch.distributed.broadcast(t, src=0)
    return tuple(type(v)(x) if isinstance(v, bool) else x for v, x in zip(values, t.tolist()))


def gather_objects(obj) -> list:
    """``[obj of rank 0, obj of rank 1, ...]`` on every rank (``[obj]`` in one process)."""
    if not is_active() or world_size() == 1:
        return [obj]
    out = [None] * world_size()
    torch.distributed.all_gather_object(out, obj)
    return out


def torchrun_command(nproc: int, module: str, argv: list[str], torchrun_args: list[str] | None = None) -> list[str]:
    """``python -m torch.distributed.run`` for ``nproc`` processes of ``python -m module argv`` on this machine
    (``--standalone`` unless ``torchrun_args`` give a rendezvous, e.g. ``--nnodes 2 --rdzv-endpoint host:29400``)."""
    if int(nproc) != nproc or nproc < 1:
        raise ValueError(f"--nproc-per-node must be a positive integer, got {nproc!r}")
    extra = list(torchrun_args or [])
    rdzv = any(a.startswith(("--rdzv", "--nnodes", "--master")) for a in extra)
    return [sys.executable, "-m", "torch.distributed.run", *([] if rdzv else ["--standalone"]),
            "--nproc-per-node", str(int(nproc)), *extra, "-m", module, *argv]


def launch(nproc: int, module: str, argv: list[str], torchrun_args: list[str] | None = None) -> int:
    """Run :func:`torchrun_command` and return its exit code; the child processes import this same magwarp."""
    import magwarp

    env = dict(os.environ)
    root = os.path.dirname(os.path.dirname(os.path.abspath(magwarp.__file__)))
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    cmd = torchrun_command(nproc, module, argv, torchrun_args)
    return subprocess.call(cmd, env=env)
