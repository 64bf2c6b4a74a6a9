"""Batched benchmark evaluation: the paper's tables (metric, n, mean ± std over repeats) for any magwarp env.

All episodes of a repeat run in parallel worlds, and as many repeats as fit in ``max_worlds`` run together (world
``w`` belongs to repeat ``w // episodes``); the metrics are the device-side accumulators of :mod:`magwarp.metrics`,
read back once per batch of repeats.

* **Pushing** (Table 1): every world plays one episode (``max_episode_steps``, ending early on a collision); a
  repeat is ``episodes`` goals. The 6D-platform pose task and the MagBot pick-and-place tasks are evaluated the
  same way (:mod:`magwarp.metrics.platform`, :mod:`magwarp.metrics.pick_place`), and so are the levitation envs
  (``magwarp/Levitation-v0`` and its variants, :mod:`magwarp.metrics.levitation`: success, tracking error, copper
  energy per episode and per success).
* **Trajectory planning** (Table 2): every world is one long-horizon run of ``steps`` env steps in which reached
  goals are replaced; a collision or a timeout ends the world's episode (its movers' pending goals fail) and a new
  one starts. Makespan: time at which the slowest mover of a world reached ``makespan_goals`` goals.
* **Swarms** (``magwarp/Swarm-v0``, ``magwarp/SwarmMaterialFlow-v0``): a swarm world has no episode end by default
  (goals stream, collided movers respawn), so the evaluated window is ``steps`` env steps per world from a fresh
  reset (default 10 s: 250 steps of 40 cycles); a repeat is ``episodes`` independent worlds, each with
  ``num_movers`` movers (``env_kwargs``, :class:`~magwarp.swarm.SwarmConfig`). Worlds that end inside the window
  (``on_collision="end"``, ``max_episode_steps``) restart and keep counting. Throughput is goals (jobs) per
  second per world and per mover, collisions are collided movers per 1000 goals, deadlocked movers are counted at
  the window's end, the makespan is the time at which the slowest mover of a world reached ``makespan_goals``
  goals (:mod:`magwarp.metrics.swarm`).

Copper energy (the coils' physical energy, :mod:`magwarp.metrics.energy`): when the env runs the magnetic model
(``env_kwargs={"force_model": "magnetic"}``, ``--env-kwargs '{"force_model": "magnetic"}'``), the table gains the
copper energy per goal (trajectory planning, swarms) or per episode (J: every mover of a repeat's worlds over the
window, divided by its goals or episodes) and the mean copper loss per mover (W), beside MagBotSim's kinematic
smoothness proxy.

Process time is the wall-clock time of the batched run (policy and simulation) per goal (trajectory planning,
swarms) or per episode (pushing, platform, pick and place). On the CPU the evaluation runs with one torch intra-op thread, for
stable timings on shared machines (the previous setting is restored afterwards).
"""

from __future__ import annotations

import contextlib
import importlib
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np
import torch

__all__ = ["EvalResult", "evaluate", "format_table", "load_policy", "resolve_env_id"]


class EvalError(ValueError):
    """A bad evaluation argument (env id, policy, sizes); the CLI reports it as one line."""


@dataclass
class Row:
    key: str
    label: str
    n: float
    mean: float
    std: float
    values: list[float] = field(default_factory=list)


@dataclass
class EvalResult:
    env_id: str
    policy: str
    family: str
    device: str
    episodes: int
    repeats: int
    steps_per_world: int
    wall_s: float
    rows: list[Row]

    def to_dict(self) -> dict:
        """Plain data for JSON (undefined values, e.g. corrections without a success, become None)."""
        def clean(x):
            if isinstance(x, float) and not math.isfinite(x):
                return None
            if isinstance(x, dict):
                return {k: clean(v) for k, v in x.items()}
            if isinstance(x, list):
                return [clean(v) for v in x]
            return x
        return clean(asdict(self))


# ---------------------------------------------------------------------------------------------------------- env ids
def resolve_env_id(env_id: str) -> str:
    """``magwarp/PushBox-v0``, ``PushBox-v0`` and ``PushBox`` all name the same env."""
    import gymnasium as gym

    import magwarp  # noqa: F401 - registers the envs

    for cand in (env_id, f"magwarp/{env_id}", f"magwarp/{env_id}-v0", f"{env_id}-v0"):
        if cand in gym.registry and cand.startswith("magwarp/"):
            return cand
    known = sorted(k for k in gym.registry if k.startswith("magwarp/"))
    raise EvalError(f"unknown env {env_id!r}; magwarp envs are e.g. {', '.join(known[:4])}, ... "
                    f"({len(known)} in all, see gymnasium.registry)")


# ---------------------------------------------------------------------------------------------------------- policies
def _flatten_obs(obs) -> torch.Tensor:
    """Dict observations as one tensor, keys in sorted order (achieved_goal, desired_goal, observation: SB3's)."""
    if isinstance(obs, dict):
        return torch.cat([obs[k].reshape(obs[k].shape[0], -1) for k in sorted(obs)], dim=1)
    return obs


class ModulePolicy:
    """A torch module (TorchScript or ``torch.save``d) as a policy: flattened observation in, actions out."""

    def __init__(self, module, env):
        self.module = module
        self.shape = (env.num_envs, *env.single_action_space.shape)
        if isinstance(module, torch.nn.Module):
            module.eval()

    @torch.no_grad()
    def __call__(self, obs) -> torch.Tensor:
        out = self.module(_flatten_obs(obs))
        if isinstance(out, (tuple, list)):
            out = out[0]
        return out.reshape(self.shape).to(torch.float32)


def scripted_policy(env) -> Callable:
    """The built-in baseline: the env's own ``scripted_policy()``, or the push heuristic for pushing tasks."""
    if hasattr(env, "scripted_policy"):
        return env.scripted_policy()
    from magwarp.envs.push import PushEnv

    if isinstance(env, PushEnv):
        from magwarp.policies.push import PushHeuristic

        return PushHeuristic(env)
    raise EvalError(f"no scripted policy for {type(env).__name__}")


def _check_residual_env(path: str, env) -> None:
    """A policy trained on a residual env (its actions correct that env's scripted baseline) is refused elsewhere:
    on the base env its corrections would act alone; one that adds the baseline itself (``residual_env_id`` in its
    metadata) is refused on the residual env, which would add it twice."""
    from magwarp.envs.residual import ResidualAction
    from magwarp.registration import _load, env_ids
    from magwarp.training.policy import policy_metadata

    try:
        meta = policy_metadata(path)
    except Exception:  # noqa: BLE001 - not a TorchScript file: it names no env
        return
    trained_on, residual_of = meta.get("env_id", ""), meta.get("residual_env_id", "")
    cls = env_ids().get(trained_on, ("",))[0]
    if cls and issubclass(_load(cls), ResidualAction) and type(env).__name__ != cls:
        raise EvalError(f"policy file {path!r} was trained on {trained_on}: its actions are corrections to that env's "
                        f"scripted baseline, not actions for {type(env).__name__}; evaluate it on {trained_on}")
    if residual_of and type(env).__name__ == env_ids().get(residual_of, ("",))[0]:
        raise EvalError(f"policy file {path!r} already adds {residual_of}'s baseline to its actions: evaluate it on "
                        f"{trained_on}")


def load_policy(spec: str, env, *, trusted: bool = False) -> Callable:
    """``scripted``, a TorchScript / ``torch.save``d module file, or ``module:callable`` (a class is instantiated
    with the env; a function is the policy ``fn(obs) -> actions``). A file is loaded without running pickled code
    (:mod:`magwarp._io`): a whole pickled module needs ``trusted=True``."""
    if spec == "scripted":
        return scripted_policy(env)
    if os.path.isfile(spec):
        from magwarp._io import UnreadableFileError, load_module

        try:
            module = load_module(spec, env.device, trusted=trusted)
        except UnreadableFileError as e:
            raise EvalError(str(e)) from None
        if not callable(module):
            raise EvalError(f"policy file {spec!r} holds a {type(module).__name__}, not a callable module")
        _check_residual_env(spec, env)
        return ModulePolicy(module, env)
    if ":" in spec:
        mod_name, _, attr = spec.partition(":")
        try:
            obj = getattr(importlib.import_module(mod_name), attr)
        except ImportError as e:
            raise EvalError(f"cannot import policy module {mod_name!r}: {e}") from None
        except AttributeError:
            raise EvalError(f"module {mod_name!r} has no attribute {attr!r}") from None
        if isinstance(obj, type):
            obj = obj(env)
        if not callable(obj):
            raise EvalError(f"policy {spec!r} is not callable")
        return obj
    raise EvalError(f"policy {spec!r} is not 'scripted', an existing file, or module:callable")


class CheckedPolicy:
    """A policy whose errors and actions are checked: an exception inside it becomes an :class:`EvalError` naming the
    policy; its actions must have the env's shape and be finite in float32 (checked on the device and read back
    once per batch by :meth:`raise_if_nonfinite`, so a policy returning NaN fails the evaluation instead of
    scoring 0 goals)."""

    def __init__(self, policy: Callable, name: str, env):
        self.policy, self.name = policy, name
        self.shape = (env.num_envs, *env.single_action_space.shape)
        self.device = env.device
        self.nonfinite = torch.zeros((), dtype=torch.bool, device=env.device)

    def __call__(self, obs) -> torch.Tensor:
        try:
            action = self.policy(obs)
        except Exception as e:  # noqa: BLE001 - the user's policy: its failure is reported as one line
            raise EvalError(f"policy {self.name!r} raised {type(e).__name__}: {_last_line(str(e))}") from e
        if not isinstance(action, torch.Tensor):
            try:
                action = torch.as_tensor(np.asarray(action, dtype=np.float64), device=self.device)
            except (TypeError, ValueError):
                raise EvalError(f"policy {self.name!r} returned a {type(action).__name__}, not actions of shape "
                                f"{self.shape}") from None
        if tuple(action.shape) != self.shape or not action.is_floating_point():
            raise EvalError(f"policy {self.name!r} returned {action.dtype} actions of shape {tuple(action.shape)}; "
                            f"the env takes floating point actions of shape {self.shape}")
        action = action.to(device=self.device, dtype=torch.float32)
        self.nonfinite |= ~torch.isfinite(action).all()
        return action

    def raise_if_nonfinite(self) -> None:
        if bool(self.nonfinite):
            raise EvalError(f"policy {self.name!r} returned non-finite actions (NaN, inf, or values beyond float32's "
                            f"range): the evaluation is void")


def _last_line(message: str) -> str:
    """The error itself from a message that carries a traceback (TorchScript's put it before the error line)."""
    lines = [line.strip() for line in message.strip().splitlines() if line.strip()]
    if len(lines) > 1 and any("Traceback" in line for line in lines):
        return lines[-1]
    return " ".join(lines)


def _checked(policy: Callable, name: str, env) -> CheckedPolicy:
    return CheckedPolicy(policy, name, env)


# ---------------------------------------------------------------------------------------------------------- running
def _family(env) -> str:
    from magwarp.envs.push import PushEnv
    from magwarp.envs.trajectory import TrajectoryPlanningEnv

    if isinstance(env, TrajectoryPlanningEnv):
        return "trajectory"
    from magwarp.swarm.env import SwarmEnv

    if isinstance(env, SwarmEnv):
        return "swarm"
    if isinstance(env, PushEnv):
        return "push"
    from magwarp.envs.gripper_pick_place import GripperPickPlaceEnv
    from magwarp.envs.platform_pick_place import PlatformPickPlaceEnv
    from magwarp.envs.platform_pose import PlatformPoseEnv

    if isinstance(env, (PlatformPickPlaceEnv, GripperPickPlaceEnv)):
        return "pick_place"
    if isinstance(env, PlatformPoseEnv):
        return "platform"
    from magwarp.envs.levitation import LevitationEnv

    if isinstance(env, LevitationEnv):
        return "levitation"
    raise EvalError(f"magwarp eval supports trajectory planning, pushing, platform, pick-and-place, swarm and "
                    f"levitation envs, not {type(env).__name__}")


def _check_device(device) -> str:
    from magwarp._checks import device_name, init_warp
    from magwarp.sim import default_device

    device = device_name(device)
    if device is None:
        return default_device()
    import warp as wp

    init_warp()
    if device != "cpu" and not (device.startswith("cuda") and device in {str(d) for d in wp.get_cuda_devices()}
                                or device == "cuda" and wp.is_cuda_available()):
        choices = "cpu or cuda:N" if wp.is_cuda_available() else "cpu"
        raise EvalError(f"device {device!r} is not available here (choose {choices})")
    return "cuda:0" if device == "cuda" else device


def evaluate(env_id: str, policy: str = "scripted", episodes: int = 100, repeats: int = 10, *,
             device: str | None = None, steps: int | None = None, makespan_goals: int = 5,
             max_worlds: int | None = None, seed: int = 0, progress: bool | None = None,
             env_kwargs: dict | None = None, trusted: bool = False) -> EvalResult:
    """Evaluate ``policy`` on ``env_id``; see the module docstring. ``steps``: env steps per world (trajectory
    planning and swarms, default 10 s: 250 steps of 40 cycles; pushing: the episode length). ``max_worlds``:
    worlds simulated at once (default 65536 on a GPU, 2048 on the CPU).

    On the CPU, torch runs with one intra-op thread for the whole evaluation (``torch.set_num_threads(1)``): the
    tensors are small, and several threads only make the process times unstable on a shared machine. The previous
    thread count is restored on return (also on an error).

    Under torchrun (``magwarp eval --nproc-per-node N``, :mod:`magwarp.training.distributed`) every rank calls this
    with its own device: a batch holds at most ceil(repeats / N) repeats, rank r runs batches r, r + N, ..., and
    every rank returns the whole result, its repeats in batch order. A batch's seeds do not depend on the rank, so
    the table equals a one-process run whose ``max_worlds`` holds as many repeats per batch."""
    episodes, repeats, makespan_goals, steps, max_worlds, seed = _check_sizes(
        episodes, repeats, makespan_goals, steps, max_worlds, seed)
    env_id = resolve_env_id(env_id)
    label, policy = policy, _pretrained_file(policy)
    if policy != "scripted" and not os.path.isfile(policy) and ":" not in policy:
        raise EvalError(f"policy {policy!r} is not 'scripted', an existing file, or module:callable")
    from magwarp.training import distributed as dist

    device = _check_device(device)
    rank, world = dist.rank(), dist.world_size()
    with _cpu_threads(device):
        max_worlds = max_worlds or (65536 if device.startswith("cuda") else 2048)
        per_batch = max(1, min(repeats, max_worlds // episodes, math.ceil(repeats / world)))
        num_batches = math.ceil(repeats / per_batch)
        env, family, episodic, num_steps, metrics, act, energy = _make_env(
            env_id, per_batch * episodes, device, seed, env_kwargs, steps, makespan_goals, policy, trusted)
        mine = range(rank, num_batches, world)  # this rank's batches
        done, wall_all = _run_batches(env, act, metrics, energy, mine, env_id, device, seed, num_steps, per_batch,
                                      repeats, episodic, progress, rank)
        values, process, wall_all = _gather_batches(dist, done, wall_all)
        rows = _result_rows(metrics, env, values, process, episodic)
        return EvalResult(env_id, label, family, device, int(episodes), int(repeats), num_steps, wall_all, rows)


def _check_sizes(episodes, repeats, makespan_goals, steps, max_worlds, seed) -> tuple:
    """The checked counts and seed (NaN, 2.5 or "3" are refused, not truncated), each as an :class:`EvalError`."""
    from magwarp._checks import as_count, as_seed

    def count(name, value):  # NaN, 2.5 or "3" are refused, not truncated
        try:
            return as_count(value, name)
        except (TypeError, ValueError):
            raise EvalError(f"--{name.replace('_', '-')} must be a positive integer, got {value!r}") from None

    episodes, repeats, makespan_goals = count("episodes", episodes), count("repeats", repeats), count(
        "makespan_goals", makespan_goals)
    steps = None if steps is None else count("steps", steps)
    max_worlds = None if max_worlds is None else count("max_worlds", max_worlds)
    try:
        seed = as_seed(seed, "--seed")
    except (TypeError, ValueError) as e:
        raise EvalError(str(e)) from None
    return episodes, repeats, makespan_goals, steps, max_worlds, seed


def _make_env(env_id, worlds, device, seed, env_kwargs, steps, makespan_goals, policy, trusted) -> tuple:
    """The unwrapped env of ``worlds`` worlds, its family, step count, metrics, checked policy and copper energy."""
    import gymnasium as gym

    from magwarp.metrics import Metrics

    family_kwargs = dict(env_kwargs or {})
    try:
        env = gym.make_vec(env_id, num_envs=worlds, device=device, check_inputs=False, seed=seed, **family_kwargs)
    except TypeError as e:  # an option the env does not take
        raise EvalError(f"env options {family_kwargs} do not fit {env_id}: {e}") from None
    except ValueError as e:  # a bad option value (a config check, an impossible placement): one line
        raise EvalError(f"env options {family_kwargs} for {env_id}: {_last_line(str(e))}") from None
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    family = _family(env)
    episodic = family not in ("trajectory", "swarm")  # one episode (one goal) per world
    if episodic:
        env.autoreset = False  # one episode per world; a finished world is frozen by the metrics
        num_steps = int(steps or env.max_episode_steps)
        metrics = Metrics(env)
    else:
        num_steps = int(steps or round(10_000 / env.num_cycles))  # 10 s of 1 ms cycles (250 steps of 40)
        metrics = Metrics(env, makespan_goals=makespan_goals)
    act = _checked(load_policy(policy, env, trusted=trusted), policy, env)
    from magwarp.metrics.energy import CopperEnergy

    energy = CopperEnergy.attach(env)  # None unless the env runs the magnetic model (force_model="magnetic")
    return env, family, episodic, num_steps, metrics, act, energy


def _run_batches(env, act, metrics, energy, mine, env_id, device, seed, num_steps, per_batch, repeats, episodic,
                 progress, rank) -> tuple[list[tuple[int, dict[str, list[float]], float]], float]:
    """Warm up, then run this rank's batches: ([(batch, metric values, process time)], wall time of the run)."""
    from tqdm import tqdm

    done: list[tuple[int, dict[str, list[float]], float]] = []  # (batch, metric values, process time)
    total = len(mine) * num_steps
    bar = tqdm(total=total, desc=f"eval {env_id}", unit="step", leave=False,
               disable=rank > 0 or ((total < 100) if progress is None else not progress))
    start_all = time.perf_counter()
    with torch.no_grad():
        # Warm-up: the first step compiles kernels and records the step graph; keep it out of the process time.
        obs, _ = env.reset(seed=seed)
        env.step(act(obs))
        act.raise_if_nonfinite()
        for batch in mine:
            obs, _ = env.reset(seed=seed + batch)
            metrics.reset()
            if energy is not None:
                energy.reset()
            _sync(device)
            start = time.perf_counter()
            for _ in range(num_steps):
                obs, _, terminated, truncated, _ = env.step(act(obs))
                if episodic:
                    metrics.freeze(terminated | truncated)
                bar.update(1)
            if episodic:  # episodes cut short by --steps still count, as unfinished (not successful)
                still = metrics.t["active"].bool()
                metrics.t["episodes"] += still
                metrics.freeze(still)
            summary = metrics.summary(per_batch)
            if energy is not None:
                sim_s = num_steps * env.num_cycles * float(env.sim.model.limits.dt)
                summary.update(energy.summary(per_batch, sim_s))
            summary = {k: v.cpu().numpy() for k, v in summary.items()}  # one sync per batch
            act.raise_if_nonfinite()
            wall = time.perf_counter() - start
            keep = min(per_batch, repeats - batch * per_batch)
            units = summary["episodes"].sum() if episodic else summary["goals_reached"].sum()
            done.append((batch, {k: [float(x) for x in v[:keep]] for k, v in summary.items()},
                         1000.0 * wall / max(float(units), 1.0)))
    bar.close()
    wall_all = time.perf_counter() - start_all
    return done, wall_all


def _gather_batches(dist, done, wall_all) -> tuple[dict[str, list[float]], list[float], float]:
    """Every rank's batches in batch order: (metric values per repeat, process times per batch, slowest wall time)."""
    values: dict[str, list[float]] = {}
    process: list[float] = []
    ranks = dist.gather_objects((done, wall_all))  # every rank's batches (one process: its own)
    for _, batch_values, ms in sorted((b for part, _ in ranks for b in part), key=lambda b: b[0]):
        for k, v in batch_values.items():
            values.setdefault(k, []).extend(v)
        process.append(ms)
    wall_all = max(w for _, w in ranks)
    return values, process, wall_all


def _result_rows(metrics, env, values: dict[str, list[float]], process: list[float], episodic: bool) -> list[Row]:
    """The table's rows: the family's metrics, copper energy and loss (magnetic model), and the process time."""
    rows = _rows(metrics.ROWS, values, env.num_movers)
    unit = "episode" if episodic else "goal"
    count = values["episodes" if episodic else "goals_reached"]
    if "copper_energy_j" in values:  # the magnetic model: the coils' physical energy
        joules = np.asarray(values["copper_energy_j"]) / np.maximum(np.asarray(count, dtype=np.float64), 1.0)
        watts = np.asarray(values["copper_power_w"])
        rows.append(Row("copper_energy_j_per_goal", f"Copper Energy (J per {unit})", float(np.mean(count)),
                        float(joules.mean()), float(joules.std()), [float(x) for x in joules]))
        rows.append(Row("copper_power_w", "Copper Loss (W per mover, mean)", float(np.mean(count)),
                        float(watts.mean()), float(watts.std()), [float(x) for x in watts]))
    rows.append(Row("process_time_ms", f"Process Time (ms per {unit}, batched)", float(np.mean(count)),
                    float(np.mean(process)), float(np.std(process)), process))
    return rows


def _pretrained_file(policy: str) -> str:
    """``pretrained:NAME`` -> the shipped policy file (:mod:`magwarp.training.pretrained`); other specs unchanged."""
    from magwarp.training.pretrained import resolve_policy

    try:
        return resolve_policy(policy)
    except ValueError as e:
        raise EvalError(str(e)) from None


@contextlib.contextmanager
def _cpu_threads(device: str):
    """One torch intra-op thread while evaluating on the CPU (stable timings); the old count is restored after."""
    if device != "cpu":
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize(torch.device(device))


def _rows(spec, values: dict[str, list[float]], num_movers: int) -> list[Row]:
    rows = []
    for key, label, count_key in spec:
        v = np.asarray(values[key], dtype=np.float64)
        n = float(np.mean(values[count_key]))
        if key.startswith("mover_mover") and num_movers < 2:
            rows.append(Row(key, label, n, float("nan"), float("nan"), []))  # shown as '---', as in the paper
            continue
        finite = v[np.isfinite(v)]
        mean = float(finite.mean()) if finite.size else float("nan")
        std = float(finite.std()) if finite.size else float("nan")
        rows.append(Row(key, label, n, mean, std, [float(x) for x in v]))
    return rows


def _fmt(x: float) -> str:
    if not math.isfinite(x):
        return "---"
    if x == 0:
        return "0"
    if abs(x) >= 1000:
        return f"{x:.2f}"
    digits = max(2, 4 - int(math.floor(math.log10(abs(x)))) - 1)
    return f"{x:.{min(digits, 6)}f}"


def format_table(result: EvalResult) -> str:
    """The paper's table: metric, n (mean count per repeat), mean ± std over repeats."""
    windows = f"worlds x {result.steps_per_world} steps"
    header = (f"{result.env_id}  policy={result.policy}  {result.repeats} repeats x {result.episodes} "
              f"{windows if result.family in ('trajectory', 'swarm') else 'episodes'}  "
              f"device={result.device}  ({result.wall_s:.1f} s)")
    lines = [header]
    w = max(len(r.label) for r in result.rows)
    lines.append(f"| {'Metric'.ljust(w)} | {'n':>8} | {'mean ± std':<24} |")
    lines.append(f"|{'-' * (w + 2)}|{'-' * 10}|{'-' * 26}|")
    for r in result.rows:
        n = f"{r.n:.0f}" if abs(r.n - round(r.n)) < 1e-9 else f"{r.n:.1f}"
        cell = "---" if not math.isfinite(r.mean) else f"{_fmt(r.mean)} ± {_fmt(r.std)}"
        lines.append(f"| {r.label.ljust(w)} | {n:>8} | {cell:<24} |")
    return "\n".join(lines)
