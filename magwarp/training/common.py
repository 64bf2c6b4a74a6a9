"""Training helpers: env construction, flattened and normalised observations, success tracking, logging, checkpoints.

Everything that touches per-step data stays on the env's device (no host sync inside a rollout); the host reads
the accumulated statistics only when a log line is written.
"""

from __future__ import annotations

import csv
import json
import os
import random
import time
from typing import Any

import numpy as np
import torch

from magwarp.training import distributed as dist

__all__ = ["OBS_KEYS", "make_env", "evaluate", "evaluate_steps", "flatten_obs", "obs_dim", "RunningMeanStd",
           "SuccessTracker", "CsvLogger", "plot_curve", "save_checkpoint", "load_checkpoint", "trust_checkpoints",
           "seed_everything", "parse_env_kwargs", "Timer", "PhaseTimer", "configure_adam", "set_lr", "autocast"]

#: order in which a goal-dict observation is flattened (the exported policy's input layout): sorted key order, as
#: gymnasium's Dict space, SB3 and ``magwarp eval`` flatten it
OBS_KEYS = ("achieved_goal", "desired_goal", "observation")


def seed_everything(seed: int, deterministic: bool = False) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    if deterministic:
        torch.use_deterministic_algorithms(True, warn_only=True)


def parse_env_kwargs(text: str | None) -> dict[str, Any]:
    """``--env-kwargs`` JSON (e.g. ``'{"layout": [[1,1],[1,1]], "num_movers": 1}'``) -> dict (lists of lists
    named ``layout`` become numpy arrays)."""
    if not text:
        return {}
    def no_constant(name):  # JSON has no NaN/Infinity; Python's parser accepts them unless told otherwise
        raise ValueError(f"--env-kwargs must hold finite numbers, got {name} in {text!r}")

    def finite_float(token):
        value = float(token)
        if not np.isfinite(value):
            raise ValueError(f"--env-kwargs must hold finite numbers, got {token} in {text!r}")
        return value

    try:
        kwargs = json.loads(text, parse_constant=no_constant, parse_float=finite_float)
    except json.JSONDecodeError as e:
        raise ValueError(f"--env-kwargs must be a JSON object, got {text!r}: {e}") from None
    if not isinstance(kwargs, dict):
        raise ValueError(f"--env-kwargs must be a JSON object, got {text!r}")
    if isinstance(kwargs.get("layout"), list):
        kwargs["layout"] = np.asarray(kwargs["layout"], dtype=np.int32)
    return kwargs


def make_env(env_id: str, num_envs: int, device: str, seed: int, env_kwargs: dict[str, Any] | None = None):
    """A batched magwarp env (``gymnasium.make_vec``) and its unwrapped base; a multi-agent env (one with
    ``agent_view()``, e.g. a swarm) comes as its flat view, every agent a sub-env (parameter-shared training)."""
    import gymnasium as gym
    import warp as wp

    import magwarp  # noqa: F401 - registers the env ids

    wp.config.quiet = True
    if str(device).startswith("cuda"):
        torch.set_float32_matmul_precision("high")  # TF32 matmuls for the networks
    if env_id not in gym.registry:
        known = sorted(k for k in gym.registry if k.startswith("magwarp/"))
        raise ValueError(f"unknown env id {env_id!r}; magwarp ids look like {known[:4]} ...")
    env = gym.make_vec(env_id, num_envs=int(num_envs), device=device, seed=int(seed), check_inputs=False,
                       **(env_kwargs or {}))
    base = getattr(env, "unwrapped", env)
    if hasattr(base, "agent_view"):  # multi-agent envs (swarms): one sub-env per agent, for parameter sharing
        env = base = base.agent_view()
    return env, base


def flatten_obs(obs) -> torch.Tensor:
    """A goal-dict observation -> ``[..., achieved_goal + desired_goal + observation]`` (a tensor passes through)."""
    if isinstance(obs, dict):
        return torch.cat([obs[k] for k in OBS_KEYS], dim=-1)
    return obs


def obs_dim(space) -> int:
    import gymnasium as gym

    if isinstance(space, gym.spaces.Dict):
        return int(sum(int(np.prod(space[k].shape)) for k in OBS_KEYS))
    return int(np.prod(space.shape))


class RunningMeanStd(torch.nn.Module):
    """Running mean/variance of a batch stream (parallel Welford), on the device; ``normalize`` clips to ±clip."""

    def __init__(self, shape: int, device, clip: float = 10.0, eps: float = 1e-4):
        super().__init__()
        self.register_buffer("mean", torch.zeros(shape, device=device, dtype=torch.float64))
        self.register_buffer("var", torch.ones(shape, device=device, dtype=torch.float64))
        self.register_buffer("count", torch.full((), eps, device=device, dtype=torch.float64))
        self.clip = float(clip)

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Add a batch; under torchrun the batch is every rank's (the moments are summed over the ranks)."""
        x = x.reshape(-1, x.shape[-1]).to(torch.float64)
        if dist.is_active() and dist.world_size() > 1:
            s = dist.all_reduce_sum_(torch.cat([x.new_full((1,), x.shape[0]), x.sum(0), x.square().sum(0)]))
            b_count = s[0]  # stays on the device (no host sync)
            b_mean = s[1:1 + x.shape[1]] / s[0]
            b_var = (s[1 + x.shape[1]:] / s[0] - b_mean.square()).clamp(min=0.0)
        else:
            b_mean, b_var, b_count = x.mean(0), x.var(0, unbiased=False), x.shape[0]
        delta = b_mean - self.mean
        tot = self.count + b_count
        self.mean += delta * b_count / tot
        m2 = self.var * self.count + b_var * b_count + delta.square() * self.count * b_count / tot
        self.var.copy_(m2 / tot)
        self.count.copy_(tot)

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        std = torch.sqrt(self.var + 1e-8).to(x.dtype)
        return ((x - self.mean.to(x.dtype)) / std).clamp(-self.clip, self.clip)


class SuccessTracker:
    """Device-side success, return and episode-length counters since the last :meth:`pop`.

    Success rate: for envs that report ``info["is_success"]`` (pushing), the fraction of finished episodes that end
    in success; for trajectory planning (``info["goals_reached"]``), goals reached / (goals reached + goals lost),
    where every mover's pending goal is lost when an episode ends by a collision or a timeout (the benchmark's rule),
    not when ``info["time_limit"]`` marks an episode-length cut.

    Goal rate (``goals_per_1k_steps``, envs with ``info["goals_reached"]``): goals reached per 1000 env steps (per
    1000 agent-steps on a swarm's flat agent view, where episodes never end and the success rate stays 1).
    """

    def __init__(self, num_envs: int, device):
        self.device = torch.device(device)
        self.ep_return = torch.zeros(num_envs, device=device)
        self.ep_len = torch.zeros(num_envs, device=device)
        self._zero()

    def _zero(self):
        z = lambda: torch.zeros((), device=self.device, dtype=torch.float64)  # noqa: E731
        self.s = {k: z() for k in ("episodes", "return", "length", "success", "trials", "collisions", "goals",
                                   "steps")}

    @torch.no_grad()
    def update(self, reward: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor, info: dict) -> None:
        done = terminated | truncated
        self.ep_return += reward
        self.ep_len += 1
        s = self.s
        s["episodes"] += done.sum()
        s["return"] += (self.ep_return * done).sum()
        s["length"] += (self.ep_len * done).sum()
        coll = torch.zeros_like(done)
        for k, v in info.items():
            if k.endswith("collision") and isinstance(v, torch.Tensor) and v.shape == done.shape:
                coll = coll | v.bool()
        s["collisions"] += coll.sum()
        if "is_success" in info:
            s["success"] += (info["is_success"] & done).sum()
            s["trials"] += done.sum()
        elif "goals_reached" in info:
            reached = info["goals_reached"]
            s["success"] += reached.sum()
            s["goals"] += reached.sum()
            s["steps"] += done.numel()
            lost = done & ~info["time_limit"] if "time_limit" in info else done
            s["trials"] += reached.sum() + lost.sum() * reached.shape[-1]
        self.ep_return.masked_fill_(done, 0.0)
        self.ep_len.masked_fill_(done, 0.0)

    def pop(self) -> dict[str, float]:
        """Host values since the last pop (one sync): success_rate, episodes, mean return/length, collisions (per
        episode and per 1000 goals)."""
        keys = list(self.s)
        totals = dist.all_reduce_sum_(torch.stack([self.s[k] for k in keys]))  # every rank's counters (torchrun)
        v = {k: float(t) for k, t in zip(keys, totals.tolist())}
        self._zero()
        eps = max(v["episodes"], 1.0)
        return {
            "success_rate": v["success"] / v["trials"] if v["trials"] > 0 else float("nan"),
            "episodes": v["episodes"],
            "ep_return": v["return"] / eps if v["episodes"] else float("nan"),
            "ep_length": v["length"] / eps if v["episodes"] else float("nan"),
            "collisions_per_episode": v["collisions"] / eps if v["episodes"] else float("nan"),
            # per 1000 goals (trajectory planning: goals reached or lost; pushing: episodes), the paper's B0 unit
            "collisions_per_1k_goals": 1000.0 * v["collisions"] / v["trials"] if v["trials"] > 0 else float("nan"),
            "goals_per_1k_steps": 1000.0 * v["goals"] / v["steps"] if v["steps"] > 0 else float("nan"),
        }


@torch.no_grad()
def evaluate(env, act, steps: int, seed: int = 12345) -> dict[str, float]:
    """Run ``act(obs) -> action`` (deterministic) for ``steps`` batched steps from a fresh reset of ``env``; the
    :class:`SuccessTracker` statistics of those steps (the env is reset again by the caller if it keeps training)."""
    return evaluate_steps(env, act, steps, seed).pop()


@torch.no_grad()
def evaluate_steps(env, act, steps: int, seed: int = 12345) -> "SuccessTracker":
    """:func:`evaluate`'s steps, issued without reading their statistics (no host sync): the tracker to pop."""
    base = getattr(env, "unwrapped", env)
    tracker = SuccessTracker(base.num_envs, base.device)
    obs, _ = env.reset(seed=seed)
    for _ in range(int(steps)):
        obs, reward, terminated, truncated, info = env.step(act(obs))
        tracker.update(reward, terminated, truncated, info)
    return tracker


class CsvLogger:
    """Appends rows to ``OUT/progress.csv`` (and TensorBoard scalars to ``OUT/tb`` when asked and installed)."""

    def __init__(self, out: str, tensorboard: bool = False, resume: bool = False):
        os.makedirs(out, exist_ok=True)
        self.path = os.path.join(out, "progress.csv")
        self.fields: list[str] | None = None
        if resume and os.path.exists(self.path):
            with open(self.path, newline="") as f:
                header = next(csv.reader(f), None)
            self.fields = header
        elif os.path.exists(self.path):
            os.remove(self.path)
        self.tb = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter

                self.tb = SummaryWriter(os.path.join(out, "tb"))
            except ImportError:
                print("tensorboard is not installed: logging to CSV only")

    def log(self, row: dict[str, float]) -> None:
        if self.fields is None:
            self.fields = list(row)
            with open(self.path, "w", newline="") as f:
                csv.writer(f).writerow(self.fields)
        with open(self.path, "a", newline="") as f:
            csv.writer(f).writerow([row.get(k, "") for k in self.fields])
        if self.tb is not None:
            step = int(row.get("global_step", 0))
            for k, v in row.items():
                if k != "global_step" and isinstance(v, (int, float)):
                    self.tb.add_scalar(k, v, step)

    def close(self) -> None:
        if self.tb is not None:
            self.tb.close()


def plot_curve(csv_path: str, png_path: str, title: str = "") -> None:
    """Success rate and episode return against env steps and wall-clock minutes, from a progress CSV."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return

    def col(name):
        return np.array([float(r[name]) if r.get(name) not in (None, "") else np.nan for r in rows])

    steps, minutes = col("global_step"), col("wall_s") / 60.0
    success = 100 * col("success_rate")
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    marker = "o" if len(rows) < 3 else None
    for ax, x, label in ((axes[0], steps, "env steps"), (axes[1], minutes, "wall-clock (min)")):
        ax.plot(x, success, color="tab:green", marker=marker)
        ax.set_xlabel(label)
        ax.set_ylabel("success rate (%)")
        ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
    axes[2].plot(steps, col("ep_return"), color="tab:blue", marker=marker)
    axes[2].set_xlabel("env steps")
    axes[2].set_ylabel("episode return")
    axes[2].grid(alpha=0.3)
    for ax in (axes[0], axes[2]):
        ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 3))
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(png_path, dpi=100)
    plt.close(fig)


def save_checkpoint(path: str, state: dict[str, Any]) -> None:
    """Atomic ``torch.save`` (a crash while writing never leaves a broken checkpoint)."""
    tmp = f"{path}.tmp"
    torch.save(state, tmp)
    os.replace(tmp, path)


#: whether :func:`load_checkpoint` may use the full unpickler (``magwarp train --trust`` sets it)
_TRUST_CHECKPOINTS = False


def trust_checkpoints(trusted: bool = True) -> None:
    """Let :func:`load_checkpoint` (default ``trusted=None``) load checkpoints with pickled objects (``--trust``)."""
    global _TRUST_CHECKPOINTS
    _TRUST_CHECKPOINTS = bool(trusted)


def checkpoint_path(path: str) -> str:
    """A run folder means its ``checkpoint.pt``."""
    return os.path.join(path, "checkpoint.pt") if os.path.isdir(path) else path


def load_checkpoint(path: str, device, *, trusted: bool | None = None) -> dict[str, Any]:
    """A checkpoint dict (file or run folder), loaded without running pickled code unless ``trusted`` (default: the
    process-wide :func:`trust_checkpoints` setting); see :mod:`magwarp._io`."""
    from magwarp._io import load_checkpoint_file

    path = checkpoint_path(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"no checkpoint at {path!r}")
    return load_checkpoint_file(path, device, trusted=_TRUST_CHECKPOINTS if trusted is None else trusted)


def _process_age() -> float:
    """Seconds since the OS started this process (Linux: ``/proc``; elsewhere 0, i.e. since this module's import)."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])  # field 22, starttime (ticks since boot)
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        age = uptime - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, AttributeError):
        return 0.0
    return age if 0.0 <= age < 60.0 else 0.0  # imported a minute or more after the start (a notebook): from the import


#: when this process started (``time.perf_counter`` scale; the interpreter's start and the torch import included where
#: the OS tells and this module is imported within the process's first minute, else its import): what --stop-after,
#: the time to target and the start-up milestones count from
PROCESS_START = time.perf_counter() - _process_age()


class Timer:
    """Wall-clock budget: ``expired`` after ``minutes`` of training (None: never), or once the whole process has run
    ``stop_after`` seconds (start-up and kernel compilation included: for machines that kill commands after a fixed
    time; keep a margin for the final evaluation and saving)."""

    def __init__(self, minutes: float | None, already: float = 0.0, stop_after: float | None = None):
        self.start = time.perf_counter()
        self.limit = None if minutes is None else 60.0 * float(minutes)
        if stop_after is not None:
            left = PROCESS_START + float(stop_after) - self.start
            self.limit = left if self.limit is None else min(self.limit, left)
        self.already = already  # wall seconds of earlier sessions (resume), for the log only

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    @property
    def total(self) -> float:
        return self.already + self.elapsed

    @property
    def expired(self) -> bool:
        return self.limit is not None and self.elapsed >= self.limit


class PhaseTimer:
    """Where a training iteration's time goes (``--profile``): ``with phases("env"): ...`` adds the wall time of the
    block, the device synchronised before and after it (so asynchronous GPU work is charged to the phase that
    launched it). Disabled (the default), a phase is a no-op context: no synchronisation, nothing recorded.
    Phases timed elsewhere (CUDA events on overlapping streams: :mod:`magwarp.training.streams`) come in through
    :meth:`add`; ``overlap`` then holds the streams' busy seconds and the iterations' wall seconds."""

    def __init__(self, device, enabled: bool = False):
        import contextlib

        self.enabled = bool(enabled)
        self.cuda = torch.device(device).type == "cuda"
        self.device = torch.device(device)
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self.overlap: dict[str, float] = {}
        self._null = contextlib.nullcontext()

    def add(self, name: str, seconds: float) -> None:
        """Add ``seconds`` (measured elsewhere) and one call to phase ``name``."""
        self.seconds[name] = self.seconds.get(name, 0.0) + float(seconds)
        self.calls[name] = self.calls.get(name, 0) + 1

    def _sync(self) -> None:
        if self.cuda:
            torch.cuda.synchronize(self.device)

    def __call__(self, name: str):
        return self._Phase(self, name) if self.enabled else self._null

    class _Phase:
        __slots__ = ("owner", "name", "t")

        def __init__(self, owner: "PhaseTimer", name: str):
            self.owner, self.name = owner, name

        def __enter__(self):
            self.owner._sync()
            self.t = time.perf_counter()

        def __exit__(self, *exc):
            self.owner._sync()
            self.owner.add(self.name, time.perf_counter() - self.t)
            return False

    def summary(self) -> dict[str, dict[str, float]]:
        """Per phase: total seconds, share of the phases' total, calls."""
        total = sum(self.seconds.values()) or 1.0
        return {k: {"s": round(v, 4), "share": round(v / total, 4), "calls": self.calls[k]}
                for k, v in self.seconds.items()}


def configure_adam(optimizers, graphed: bool, device, fused: bool = False) -> None:
    """Capturable Adam (device step counters, a tensor lr that a captured graph reads) when ``graphed``; plain floats
    otherwise; the fused implementation (one kernel per step, its step counters on the device) when ``fused``. Also
    after loading a state saved another way (a run may resume graphed or eager; a loaded state's options win over the
    optimiser's own, so they are set again here)."""
    device = torch.device(device)
    for opt in optimizers:
        for group in opt.param_groups:
            lr = float(group["lr"])
            group["capturable"] = graphed
            group["lr"] = torch.tensor(lr, device=device) if graphed else lr
            group["fused"] = bool(fused)
            if fused:
                group["foreach"] = None  # fused and foreach exclude each other
        for state in opt.state.values():
            if "step" in state:
                state["step"] = state["step"].to(device if graphed or fused else "cpu", torch.float32)


def set_lr(optimizers, value: float) -> None:
    """Set every group's learning rate (a tensor lr in place: a captured graph reads it)."""
    for opt in optimizers:
        for group in opt.param_groups:
            if isinstance(group["lr"], torch.Tensor):
                group["lr"].fill_(value)
            else:
                group["lr"] = value


def autocast(device, amp: str):
    """``torch.autocast`` for ``--amp bf16`` on the device's type; a no-op context for ``--amp off``."""
    import contextlib

    if amp in (None, "off"):
        return contextlib.nullcontext()
    if amp != "bf16":
        raise ValueError(f"--amp must be 'off' or 'bf16', got {amp!r}")
    return torch.autocast(torch.device(device).type, dtype=torch.bfloat16)
