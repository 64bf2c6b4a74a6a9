"""What the PPO and SAC + HER modules share around their algorithm: the run options (budget, output, logging,
time-to-target), filling unset options from a checkpoint and a preset, the progress bar, the periodic deterministic
evaluation that finds the time to target, and the run's JSON summary (``OUT/run.json``).

Time to target: every ``--eval-every`` seconds of training, the deterministic policy (what ``policy.pt`` runs) plays
``--target-eval-steps`` batched steps on a separate env of ``--eval-envs`` worlds built with the evaluation options
(``--eval-env-kwargs``, else the training ones). The first evaluation whose success rate reaches ``--target`` (by
default the paper's figure for the task: :data:`PAPER_TARGETS`), with fewer collisions per 1000 goals than
``--target-collisions`` where set (by default B0's 2.14: :data:`PAPER_COLLISIONS`), gives the time to target:
seconds since the process started (start-up and compilation included), training seconds (earlier sessions of a
resumed run included) and env steps. It is printed and written to ``OUT/run.json`` with every evaluation of the run.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import time
from typing import Any, Callable

import torch

from magwarp.training import distributed as dist
from magwarp.training.common import (PROCESS_START, CsvLogger, PhaseTimer, SuccessTracker, Timer, evaluate,
                                     evaluate_steps, load_checkpoint, make_env, obs_dim, parse_env_kwargs, plot_curve,
                                     seed_everything)

__all__ = ["PAPER_TARGETS", "PAPER_COLLISIONS", "default_target", "default_target_collisions", "add_run_args",
           "resolve_run_args", "run_training", "entry_point",
           "open_env", "ProgressBar", "TargetEval", "Session", "finished_line", "write_run_json"]

#: success rates the paper reports for its tasks (Tables 3 and 5): the default ``--target`` of a run on that task
PAPER_TARGETS = {"TrajectoryPlanningB0": 0.99, "PushBox": 0.99, "PushT": 0.73, "PushWithObstacles": 0.91}
#: collisions per 1000 goals the paper reports (Table 5, simulation): the default ``--target-collisions``
PAPER_COLLISIONS = {"TrajectoryPlanningB0": 2.14}


def _task(env_id: str) -> str:
    return env_id.split("/")[-1].split("-v")[0]


def default_target(env_id: str) -> float | None:
    """The paper's success rate for ``env_id``'s task (``magwarp/PushBox-v0`` -> 0.99), None for other tasks."""
    return PAPER_TARGETS.get(_task(env_id))


def default_target_collisions(env_id: str) -> float | None:
    """The paper's collisions per 1000 goals for ``env_id``'s task (B0: 2.14), None for other tasks."""
    return PAPER_COLLISIONS.get(_task(env_id))


def add_run_args(p: argparse.ArgumentParser, default_env: str, out_suffix: str) -> None:
    """The options every training module takes (env, device, budget, output, logging, time to target, torchrun)."""
    p.add_argument("--env-id", default=None, help=f"magwarp env id (default: {default_env})")
    p.add_argument("--env-kwargs", default=None,
                   help='JSON env options, e.g. \'{"layout": [[1,1],[1,1]], "num_movers": 1}\'')
    p.add_argument("--eval-env-kwargs", default=None,
                   help="JSON env options that `magwarp eval` applies to this policy (stored in policy.pt)")
    p.add_argument("--device", default=None,
                   help="cpu or cuda[:N] (default: cuda when available; under torchrun: cuda:LOCAL_RANK)")
    p.add_argument("--seed", type=int, default=None, help="seed (rank r of a torchrun job uses seed + r)")
    p.add_argument("--out", default=None, help=f"run folder (default: runs/<env>_{out_suffix})")
    p.add_argument("--resume", default=None, help="checkpoint file or run folder to continue (its options are reused)")
    p.add_argument("--minutes", type=float, default=None, help="wall-clock training budget of this session")
    p.add_argument("--total-steps", type=float, default=None, help="stop after this many env steps (all worlds)")
    p.add_argument("--stop-after", type=float, default=None,
                   help="stop training once the process has run this many seconds (start-up and compilation included)")
    p.add_argument("--num-envs", type=int, default=None, help="parallel worlds (per rank under torchrun)")
    p.add_argument("--log-every", type=float, default=10.0, help="seconds between log lines")
    p.add_argument("--checkpoint-every", type=float, default=60.0, help="seconds between checkpoints")
    p.add_argument("--eval-steps", type=int, default=200,
                   help="batched steps of a final deterministic evaluation on the training env (0: none)")
    p.add_argument("--target", type=float, default=None,
                   help="success rate (a fraction, e.g. 0.99) whose first crossing in the periodic deterministic "
                        "evaluation is the time to target (default: the paper's figure for the task, e.g. 0.99 for "
                        "B0 and Push-Box, 0.73 Push-T, 0.91 PushWithObstacles; other tasks: none, unless given)")
    p.add_argument("--target-collisions", type=float, default=None,
                   help="the target also needs fewer collisions per 1000 goals than this in the periodic evaluation "
                        "(default: the paper's figure, 2.14 for B0; other tasks: none; 0 or less: none)")
    p.add_argument("--eval-every", type=float, default=None,
                   help="training seconds between the periodic evaluations (default 10 with a target; 0: none)")
    p.add_argument("--eval-envs", type=int, default=None,
                   help="worlds of the periodic evaluation (default: min(--num-envs, 1024); pushing tasks: 256; per "
                        "rank)")
    p.add_argument("--target-eval-steps", type=int, default=None,
                   help="batched steps of each periodic evaluation (default: one episode of a pushing task, 10 s of "
                        "trajectory planning)")
    p.add_argument("--stop-at-target", action="store_true", help="stop training once the target is reached")
    p.add_argument("--past-target", type=float, default=0.0,
                   help="with --stop-at-target: train this many seconds more after the first crossing (a policy "
                        "that holds the target, not one that touched it once)")
    p.add_argument("--dist-timeout", type=float, default=300.0,
                   help="seconds a torchrun rank waits in a collective before the job fails (a rank that died)")
    p.add_argument("--tensorboard", action="store_true", help="also log to OUT/tb (needs tensorboard)")
    p.add_argument("--no-progress", action="store_true", help="no tqdm bar")
    p.add_argument("--torch-threads", type=int, default=None,
                   help="torch CPU threads (default on a CPU device: 1, fastest for these small networks)")
    p.add_argument("--deterministic", action="store_true", help="deterministic torch algorithms (tests)")
    p.add_argument("--matmul-precision", choices=("highest", "high", "medium"), default=None,
                   help="torch float32 matmul precision on CUDA (default high: TF32)")
    p.add_argument("--profile", action="store_true",
                   help="time the phases of an iteration (env, policy, update, buffer, log, eval; the device is "
                        "synchronised around each, which slows training): printed and written to run.json")


def resolve_run_args(args: argparse.Namespace, presets: dict[str, dict], default_env: str,
                     out_suffix: str) -> argparse.Namespace:
    """Fill unset options: from the checkpoint when resuming, then the task preset, then the defaults."""
    if args.resume:
        saved = load_checkpoint(args.resume, "cpu")["args"]
        for k, v in saved.items():
            # stop_after: a limit of the earlier process, not of this one; out: a run continues where its checkpoint
            # is now (a copied or moved folder), not in the folder it was first written to
            if k in ("stop_after", "out"):
                continue
            if getattr(args, k, None) is None:
                setattr(args, k, v)
        if args.out is None:
            args.out = args.resume if os.path.isdir(args.resume) else os.path.dirname(args.resume)
    args.env_id = args.env_id or default_env
    family = next((k for k in presets if k != "default" and k in args.env_id), "default")
    for k, v in {**presets["default"], **presets[family]}.items():
        if getattr(args, k, None) is None:
            setattr(args, k, v)
    if args.device is None:
        args.device = "cuda" if torch.cuda.is_available() else "cpu"
    args.seed = 0 if args.seed is None else args.seed
    args.out = args.out or os.path.join("runs", args.env_id.split("/")[-1] + "_" + out_suffix)
    parse_env_kwargs(args.eval_env_kwargs)  # a bad JSON fails now, not when the policy is saved
    if args.target is None:
        args.target = default_target(args.env_id)
    if args.target is not None and not 0.0 < args.target <= 1.0:
        raise ValueError(f"--target is a success rate in (0, 1], got {args.target!r}")
    if args.target_collisions is None:
        args.target_collisions = default_target_collisions(args.env_id)
    if args.target_collisions is not None and not math.isfinite(args.target_collisions):
        raise ValueError(f"--target-collisions must be a finite number, got {args.target_collisions!r}")
    args.matmul_precision = args.matmul_precision or "high"
    if args.eval_every is None:
        args.eval_every = 10.0 if args.target is not None else 0.0
    if args.eval_every < 0:
        raise ValueError(f"--eval-every must be >= 0 seconds, got {args.eval_every!r}")
    if args.minutes is None and args.total_steps is None and args.stop_after is None:
        raise ValueError("give a budget: --minutes, --total-steps and/or --stop-after")
    return args


def run_training(args: argparse.Namespace, resolve: Callable, body: Callable[[argparse.Namespace], dict]) -> dict:
    """``body(resolve(args))`` on this rank's device (:func:`dist.setup`: a torchrun rank joins its process group)
    with torch's CPU threads set for a CPU run (1 unless ``--torch-threads``); threads and group restored after."""
    args = resolve(args)
    args.device = dist.setup(args.device, args.dist_timeout)
    threads = torch.get_num_threads()
    if args.torch_threads or str(args.device).startswith("cpu"):
        torch.set_num_threads(args.torch_threads or 1)
    ok = False
    try:
        summary = body(args)
        ok = True
        return summary
    finally:
        torch.set_num_threads(threads)
        dist.shutdown(wait=ok)


def entry_point(parse_args: Callable, train: Callable) -> Callable[[list[str] | None], int]:
    """A training module's ``main(argv) -> 0``: parse the options and train. Under torchrun a rank's exception is
    recorded (``torch.distributed.elastic``'s ``record``), so the job's error report shows the failing rank's
    traceback."""
    from torch.distributed.elastic.multiprocessing.errors import record

    @record
    def main(argv: list[str] | None = None) -> int:
        train(parse_args(argv))
        dist.leave(0)  # a torchrun rank: done (its process group is destroyed), exit without teardown
        return 0

    return main


def open_env(args: argparse.Namespace):
    """Seed this rank (``seed + rank``), build its training env and the run folder (rank 0). Returns
    ``(seed, env, base, n_obs, n_act, action_scale)``: sizes of the flattened observation and the action, and the
    action space's bound (policies act in [-1, 1], scaled by it)."""
    seed = dist.rank_seed(args.seed)
    seed_everything(seed, args.deterministic)
    env, base = make_env(args.env_id, args.num_envs, args.device, seed, parse_env_kwargs(args.env_kwargs))
    if base.device.type == "cuda":
        torch.set_float32_matmul_precision(getattr(args, "matmul_precision", None) or "high")
    n_obs, n_act = obs_dim(base.single_observation_space), int(base.single_action_space.shape[0])
    action_scale = torch.as_tensor(base.single_action_space.high, device=base.device, dtype=torch.float32)
    if dist.is_main():
        os.makedirs(args.out, exist_ok=True)
    return seed, env, base, n_obs, n_act, action_scale


class ProgressBar:
    """A tqdm bar over env steps (with ``--total-steps``) or seconds, on rank 0 unless ``--no-progress``."""

    def __init__(self, args: argparse.Namespace, timer, total: int | None, desc: str):
        self.bar, self.total = None, total
        if not args.no_progress and dist.is_main():
            from tqdm import tqdm

            self.bar = tqdm(total=total if total else max(int(timer.limit), 1), unit="step" if total else "s",
                            unit_scale=bool(total), desc=f"{desc} {args.env_id.split('/')[-1]}", dynamic_ncols=True,
                            mininterval=1.0)

    def show(self, global_step: int, timer, success_rate: float) -> None:
        if self.bar is None:
            return
        self.bar.n = min(global_step, self.total) if self.total else min(int(timer.elapsed), self.bar.total)
        self.bar.set_postfix_str(f"{global_step:,} steps, {global_step / max(timer.elapsed, 1e-9):,.0f} steps/s, "
                                 f"success {success_rate:.3f}", refresh=False)
        self.bar.update(0)  # redraws at most once per mininterval

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def log_line(self, global_step: int, sps: float, stats: dict) -> None:
        """The log line printed instead of the bar (rank 0)."""
        if self.bar is None and dist.is_main():
            rate = stats.get("goals_per_1k_steps", float("nan"))
            print(f"step {global_step:>12,}  {sps:>10,.0f} steps/s  success {stats['success_rate']:.3f}  "
                  f"return {stats['ep_return']:.2f}" + (f"  goals/1k steps {rate:.2f}" if math.isfinite(rate) else ""))


class TargetEval:
    """The periodic deterministic evaluation of a run and its time to target (see the module docstring).

    Off without a target or with ``--eval-every 0``. Under torchrun every rank evaluates its own worlds (seeds
    differ per rank) and the success counts are summed over the ranks, so all ranks see the same result."""

    def __init__(self, args: argparse.Namespace, device, saved: dict | None = None, stream=None):
        self.target = args.target
        self.stream = stream  # a CUDA stream of the evaluation's own (:meth:`launch`): its env is built and run there
        self.pending: tuple | None = None  # a launched evaluation: (tracker, done event, start, wall_s, global_step)
        limit = getattr(args, "target_collisions", None)  # checkpoints of earlier versions lack it
        self.max_collisions = float(limit) if limit is not None and limit > 0 else None
        self.every = float(args.eval_every or 0.0)
        self.enabled = self.target is not None and self.every > 0
        saved = saved or {}
        self.history: list[dict[str, float]] = list(saved.get("evals", []))
        self.reached: dict[str, float] | None = saved.get("reached")
        self.next_at = self.every
        self.env = None
        if not self.enabled:
            return
        kwargs = parse_env_kwargs(args.eval_env_kwargs or args.env_kwargs)
        # pushing tasks: 256 worlds (a mujoco-warp evaluation costs seconds whatever its size: with 2048 worlds every
        # 10 s it took 60% of a Push-Box run on an H100); trajectory planning: up to 1024, for the collision rate
        default = 256 if "/Push" in str(args.env_id) else 1024
        n = int(args.eval_envs or min(int(args.num_envs), default))
        if n < 1:
            raise ValueError(f"--eval-envs must be a positive integer, got {n}")
        self.seed = dist.rank_seed(args.seed) + 20_000
        with self._on_stream():  # the env's graphs launch on the stream current at its construction
            self.env, base = make_env(args.env_id, n, str(device), self.seed, kwargs)
        self.steps = int(args.target_eval_steps or _episode_steps(base))

    def _on_stream(self):
        """Torch's and Warp's current stream are the evaluation's own (if any): what the env's construction and steps
        issue (its graphs, and Warp's allocations and memsets too) stays in that stream's order."""
        stack = contextlib.ExitStack()
        if self.stream is not None:
            stack.enter_context(torch.cuda.stream(self.stream))
            if hasattr(self.stream, "cuda_stream"):  # a torch CUDA stream, now torch's current one
                import warp as wp

                from magwarp._streams import torch_stream

                # Warp's one wrapper of that stream (a temporary one would unregister it when collected); entering
                # waits for Warp's previous stream
                stack.enter_context(wp.ScopedStream(torch_stream(self.stream.device)))
        return stack

    def due(self, timer) -> bool:
        return self.enabled and self.pending is None and timer.elapsed >= self.next_at

    def run(self, act: Callable, timer, global_step: int) -> dict[str, float]:
        """Evaluate ``act`` now; record the first crossing of the target. Returns the evaluation's statistics."""
        self.next_at = timer.elapsed + self.every
        t = time.perf_counter()
        ev = evaluate(self.env, act, self.steps, seed=self.seed)
        return self._record(ev, t, timer.total, global_step)

    def launch(self, snapshot: Callable[[], Callable], timer, global_step: int) -> None:
        """Start an evaluation without waiting for it (``--async-eval``): on the evaluation's stream, ``snapshot()``
        returns the policy to evaluate (a copy of the learner's, made there) and the evaluation's steps are issued
        behind it; :meth:`poll` records the result once the device is done (no host sync before). Without a stream
        (the CPU) the evaluation runs now and the next :meth:`poll` records it."""
        self.next_at = timer.elapsed + self.every
        t = time.perf_counter()
        with self._on_stream():
            tracker = evaluate_steps(self.env, snapshot(), self.steps, seed=self.seed)
            done = None
            if self.stream is not None:
                done = torch.cuda.Event()
                done.record(self.stream)
        self.pending = (tracker, done, t, timer.total, global_step)

    def poll(self, block: bool = False) -> dict[str, float] | None:
        """Record a launched evaluation if the device has finished it (``block``: wait for it); its statistics, or
        None (none pending, or not done). Its row holds the training seconds and env steps of the policy it evaluated
        and the process seconds of when its result was read (``eval_s``: since its launch)."""
        if self.pending is None:
            return None
        tracker, done, t, wall_s, global_step = self.pending
        if done is not None and not block and not done.query():
            return None
        self.pending = None
        with self._on_stream():
            ev = tracker.pop()
        return self._record(ev, t, wall_s, global_step)

    def _record(self, ev: dict[str, float], start: float, wall_s: float, global_step: int) -> dict[str, float]:
        now = time.perf_counter()
        row = {"process_s": round(now - PROCESS_START, 2), "eval_s": round(now - start, 2), "wall_s": round(wall_s, 2),
               "global_step": int(global_step), "success_rate": ev["success_rate"],
               "collisions_per_episode": ev["collisions_per_episode"],
               "collisions_per_1k_goals": ev["collisions_per_1k_goals"], "episodes": ev["episodes"]}
        self.history.append(row)
        if self.reached is None and self.met(ev):
            self.reached = row
            if dist.is_main():
                also = "" if self.max_collisions is None else \
                    f", {ev['collisions_per_1k_goals']:.2f} < {self.max_collisions:g} collisions per 1000 goals"
                print(f"time to target: success {ev['success_rate']:.4f} >= {self.target}{also} after "
                      f"{row['process_s']:.1f} s (process), {row['wall_s']:.1f} s of training, "
                      f"{global_step:,} env steps")
        return ev

    def met(self, ev: dict[str, float]) -> bool:
        """Whether an evaluation reaches the target: the success rate, and fewer collisions per 1000 goals than
        ``--target-collisions`` when set."""
        ok = math.isfinite(ev["success_rate"]) and ev["success_rate"] >= self.target
        if ok and self.max_collisions is not None:
            ok = math.isfinite(ev["collisions_per_1k_goals"]) and ev["collisions_per_1k_goals"] < self.max_collisions
        return ok

    @property
    def hit(self) -> bool:
        return self.reached is not None

    def state(self) -> dict[str, Any]:
        return {"evals": self.history, "reached": self.reached}

    def summary(self) -> dict[str, Any]:
        """Fields of the run's summary: the target and the time to target (None when not reached)."""
        r = self.reached or {}
        return {"target": self.target, "target_collisions": self.max_collisions, "time_to_target_s": r.get("process_s"),
                "time_to_target_train_s": r.get("wall_s"), "time_to_target_step": r.get("global_step")}

    def close(self) -> None:
        if self.env is not None:
            self.env.close()


def _episode_steps(base) -> int:
    """One episode of a pushing task; 10 s of trajectory planning (what ``magwarp eval`` runs per world)."""
    from magwarp.envs.push import PushEnv

    if isinstance(base, PushEnv):
        return int(base.max_episode_steps)
    return int(round(10_000 / base.num_cycles))


class Session:
    """The bookkeeping of one training session around its algorithm: success tracking, the clock and budget, the
    progress bar, the periodic evaluation (time to target), the CSV log, checkpoint times, the final deterministic
    evaluation and the run's files. Under torchrun, rank 0's clock decides (:func:`dist.agree`) and rank 0 writes.

    The algorithm calls :meth:`start` once its env has compiled, :meth:`step_done` after every iteration (PPO) or env
    step (SAC), and :meth:`finish` at the end."""

    def __init__(self, args: argparse.Namespace, algo: str, device, target_state: dict | None,
                 num_agents: int | None = None, eval_stream=None):
        self.args, self.algo = args, algo
        # agents per rank: the worlds, or (agent views: swarms) every mover of every world
        self.tracker = SuccessTracker(num_agents or args.num_envs, device)
        self.logger = CsvLogger(args.out, args.tensorboard, resume=bool(args.resume)) if dist.is_main() else None
        self.target = TargetEval(args, device, target_state, eval_stream)
        self.phases = PhaseTimer(device, getattr(args, "profile", False))
        self.stats: dict[str, float] = {"success_rate": float("nan")}

    def start(self, wall_before: float, global_step: int) -> bool:
        """Start the clock; True if the budget is already spent (then train no further)."""
        args = self.args
        self.timer = Timer(args.minutes, wall_before, args.stop_after)
        self.total = None if args.total_steps is None else int(args.total_steps)
        self.bar = ProgressBar(args, self.timer, self.total, self.algo)
        self.last_log = self.last_ckpt = time.perf_counter()
        self.steps_at_log = self.start_step = global_step
        (done,) = dist.agree(self._spent(global_step))
        return done

    def _spent(self, global_step: int) -> bool:
        return self.timer.expired or (self.total is not None and global_step >= self.total)

    def step_done(self, global_step: int, act: Callable, head: dict, tail: Callable[[], dict],
                  snapshot: Callable[[], Callable] | None = None) -> tuple[bool, bool]:
        """Evaluate, log and report as due; returns (stop, checkpoint now). A log row is ``global_step``, ``head``
        (e.g. the iteration), wall seconds, steps/s, the success statistics, then ``tail()`` (losses: read only
        when a row is written). With ``snapshot`` (one process only), the periodic evaluation is launched on its own
        stream (:meth:`TargetEval.launch`) and recorded by a later call once done."""
        args, timer, target = self.args, self.timer, self.target
        now = time.perf_counter()
        stop, log_now, ckpt_now, eval_now = dist.agree(
            self._spent(global_step) or self._past_target(), now - self.last_log >= args.log_every,
            now - self.last_ckpt >= args.checkpoint_every, target.due(timer))
        if eval_now:
            with self.phases("eval"):
                if snapshot is not None:
                    target.launch(snapshot, timer, global_step)
                else:
                    target.run(act, timer, global_step)
        if target.pending is not None:
            with self.phases("eval"):
                eval_now = target.poll() is not None
        if eval_now:
            if not getattr(args, "past_target", 0.0):  # else the next step's agreed check stops (same on all ranks)
                stop = stop or (args.stop_at_target and target.hit)
        with self.phases("log"):
            self._log(global_step, now, head, tail, log_now or stop)
        if ckpt_now:
            self.last_ckpt = now
        return stop, ckpt_now

    def _past_target(self) -> bool:
        """--stop-at-target: the target was reached --past-target seconds of training ago (or more)."""
        args, target = self.args, self.target
        if not (args.stop_at_target and target.hit):
            return False
        return self.timer.total >= float(target.reached["wall_s"]) + float(getattr(args, "past_target", 0.0) or 0.0)

    def _log(self, global_step: int, now: float, head: dict, tail: Callable[[], dict], log_now: bool) -> None:
        timer = self.timer
        if log_now:
            self.stats = self.tracker.pop()
            sps = (global_step - self.steps_at_log) / max(now - self.last_log, 1e-9)
            row = {"global_step": global_step, **head, "wall_s": round(timer.total, 2), "sps": round(sps),
                   **self.stats, **tail()}
            if self.logger is not None:
                self.logger.log(row)
            self.last_log, self.steps_at_log = now, global_step
            self.bar.log_line(global_step, sps, self.stats)
        self.bar.show(global_step, timer, self.stats["success_rate"])

    def finish(self, env, act: Callable, global_step: int, seed: int, save_all: Callable[[dict], None],
               title: str, extra: dict | None = None) -> dict:
        """The final deterministic evaluation on the training env, the last checkpoint and policy, ``run.json`` and
        the curve; returns the run's summary (with the session's env steps per second and ``extra``, the algorithm's
        own fields)."""
        args, target = self.args, self.target
        self.bar.close()
        elapsed = self.timer.elapsed
        target.poll(block=True)  # a launched evaluation: its result
        summary = {"success_rate": self.stats["success_rate"], "global_step": global_step,
                   "wall_s": round(self.timer.total, 1),
                   "env_steps_per_s": round((global_step - self.start_step) / max(elapsed, 1e-9), 1),
                   **(extra or {}), **target.summary()}
        if self.phases.enabled:
            summary["profile"] = self.phases.summary()
            if dist.is_main():
                print("profile: " + ", ".join(f"{k} {v['s']:.2f} s ({100 * v['share']:.0f}%)"
                                              for k, v in summary["profile"].items()))
            o = self.phases.overlap
            if o:  # overlapping streams: each stream's busy time against the iterations' wall time
                summary["profile_overlap"] = {k: round(v, 4) for k, v in o.items()}
                if dist.is_main():
                    print(f"profile (overlapping streams, device synchronised once per iteration): "
                          f"{o['iterations']:.0f} iterations, {o['iteration_s']:.2f} s; env stream busy "
                          f"{o['env_stream_s']:.2f} s, learner stream busy {o['learner_stream_s']:.2f} s")
        if args.eval_steps > 0:  # the deterministic policy (what policy.pt runs), from fresh episodes
            ev = evaluate(env, act, args.eval_steps, seed=seed + 10_000)
            summary.update({f"eval_{k}": v for k, v in ev.items()})
            if dist.is_main():
                print(f"deterministic evaluation ({args.eval_steps} steps x {args.num_envs * dist.world_size()} envs):"
                      f" success {ev['success_rate']:.4f}, collisions/episode {ev['collisions_per_episode']:.4f}, "
                      f"{ev['episodes']:.0f} episodes")
        save_all(summary)
        if dist.is_main():
            self.logger.close()
            write_run_json(args.out, self.algo, args, summary, target)
            plot_curve(self.logger.path, os.path.join(args.out, "curve.png"), f"{title} {args.env_id} ({args.device})")
            print(finished_line(args.out, self.stats, summary, target))
        target.close()
        return summary


def finished_line(out: str, stats: dict, summary: dict, target: TargetEval) -> str:
    """The last line of a run: what was saved, the final training success and the time to target."""
    line = f"saved {out}/policy.pt, checkpoint.pt, progress.csv, curve.png, run.json; final success " \
           f"{stats['success_rate']:.3f}"
    if target.target is not None:
        ttt = summary["time_to_target_s"]
        line += f"; time to target ({target.target:g}): " + ("not reached" if ttt is None else f"{ttt:.1f} s")
    return line


def write_run_json(out: str, algo: str, args: argparse.Namespace, summary: dict, target: TargetEval) -> str:
    """``OUT/run.json``: the options, the summary (time to target included) and every periodic evaluation."""
    path = os.path.join(out, "run.json")
    data = {"algo": algo, "env_id": args.env_id, "summary": summary, "evals": target.history,
            "args": {k: v for k, v in vars(args).items() if k != "resume"}}
    tmp = f"{path}.tmp"
    with open(tmp, "w") as f:
        json.dump(data, f, indent=2, default=str, allow_nan=True)
    os.replace(tmp, path)
    return path
