"""Where a training iteration's time goes: PPO on B0 and SAC+HER on Push-Box, before (the settings of the earlier
round) and after (today's presets and time-to-target levers), in the same run: env steps/s and each phase's share of
the time (env, policy forward and rollout bookkeeping, update, replay buffer and HER relabelling, periodic evaluation,
logging; ``--profile``: the device is synchronised around each phase; with SAC's ``--overlap``, the default on CUDA,
the phases are timed on their streams with CUDA events and the device is synchronised once per iteration, so their
shares are of the streams' busy time). ``--sizes`` adds the env step at several world counts and the SAC update (one
minibatch) eager and as a replayed CUDA graph at several batch sizes.

    python benchmarks/training_profile.py --device cuda:0 --json training_profile.json
    python benchmarks/training_profile.py --device cuda:0 --sizes --json training_profile.json   # also the sizes
    python benchmarks/training_profile.py --smoke                                                # CPU check
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from common import header_line, machine_info, print_table


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def env_step_ms(env_id: str, kwargs: dict, num_envs: int, device: str, steps: int) -> float:
    """Mean wall time of one batched env step with random actions (after a warm-up step that compiles)."""
    import gymnasium as gym

    env = gym.make_vec(env_id, num_envs=num_envs, device=device, seed=0, check_inputs=False, **kwargs).unwrapped
    env.reset(seed=0)
    n_act = env.single_action_space.shape[0]
    high = torch.as_tensor(env.single_action_space.high, device=env.device)
    env.step((torch.rand(num_envs, n_act, device=env.device) * 2 - 1) * high)
    _sync(device)
    t = time.perf_counter()
    for _ in range(steps):
        env.step((torch.rand(num_envs, n_act, device=env.device) * 2 - 1) * high)
    _sync(device)
    ms = 1000 * (time.perf_counter() - t) / steps
    env.close()
    return ms


def update_ms(sac, batch: int, graph: str, device: str, minibatches: int = 32, rounds: int = 5) -> float:
    """Wall time per SAC update (one minibatch: critic, actor, temperature, Polyak) of the training preset's nets,
    for Push-T's observation (10 + 4 goal values, 2 actions)."""
    args = sac.resolve_args(sac.parse_args(["--env-id", "magwarp/PushT-v0", "--device", device, "--total-steps", "1",
                                            "--cuda-graph", graph]))
    learner = sac.SacLearner(14, 2, args, torch.device(device))
    dims = {"achieved_goal": 4, "desired_goal": 4, "observation": 6}
    n = batch * minibatches
    sample = {}
    for k, d in dims.items():
        sample[k] = sample["next_" + k] = torch.randn(n, d, device=device)
    sample.update(action=torch.rand(n, 2, device=device), reward=-torch.rand(n, device=device),
                  terminated=torch.zeros(n, dtype=torch.bool, device=device))
    learner.learn(sample, minibatches)  # capture / warm-up
    _sync(device)
    t = time.perf_counter()
    for _ in range(rounds):
        learner.learn(sample, minibatches)
    _sync(device)
    return 1000 * (time.perf_counter() - t) / (rounds * minibatches)


# (label, paper run, training options): "before" is the previous round's settings, "after" today's defaults
PROFILES = (
    ("B0 PPO", "before", "b0_ppo_starts40", ["--num-envs", "4096", "--num-steps", "32", "--num-minibatches", "4",
                                             "--cuda-graph", "off", "--eval-every", "10", "--eval-envs", "1024"]),
    ("B0 PPO", "after", "b0_ppo_starts40", ["--eval-every", "5", "--eval-envs", "2048"]),
    ("Push-Box SAC+HER", "before", "pushbox_sac", ["--eval-every", "10", "--eval-envs", "1024", "--overlap", "off"]),
    ("Push-Box SAC+HER", "after", "pushbox_sac", ["--eval-every", "10", "--eval-envs", "256"]),
)
_SMOKE = {"ppo": ["--num-envs", "16", "--num-steps", "8", "--hidden", "32,32", "--eval-every", "1", "--eval-envs", "8"],
          "sac-her": ["--num-envs", "8", "--batch-size", "64", "--updates-per-step", "2", "--buffer-steps", "64",
                      "--hidden", "32,32", "--learning-starts", "2", "--eval-every", "1", "--eval-envs", "4"]}
PHASES = ("env", "policy", "update", "buffer", "sample", "eval", "log")


def phase_profile(run_name: str, options: list[str], device: str, seconds: float, smoke: bool, out: str) -> dict:
    """Train ``run_name`` for ``seconds`` with ``--profile``: env steps/s and each phase's share."""
    import importlib

    from magwarp.training.paper import PAPER_RUNS

    run = PAPER_RUNS[run_name]
    module = importlib.import_module(run.module)
    argv = ["--env-id", run.env_id, "--env-kwargs", run.train_json(), "--eval-env-kwargs", run.eval_json(),
            "--device", device, "--out", out, "--minutes", str(seconds / 60.0), "--no-progress", "--profile",
            "--eval-steps", "0", "--checkpoint-every", "1e9", "--log-every", "1e9", *options]
    if smoke:
        argv += _SMOKE[run.algo]
    summary = module.train(module.parse_args(argv))
    prof = summary["profile"]
    total = sum(v["s"] for v in prof.values())
    row = {"env_steps_per_s": summary["global_step"] / max(summary["wall_s"], 1e-9), "profiled_s": total,
           "env_steps": summary["global_step"]}
    row.update({f"{k}_pct": 100 * prof[k]["share"] if k in prof else 0.0 for k in PHASES})
    # --overlap (SAC on CUDA): the phases ran on two streams at once; each stream's busy seconds and the iterations'
    row.update({f"overlap_{k}": v for k, v in summary.get("profile_overlap", {}).items()})
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: cuda:0 when available)")
    p.add_argument("--seconds", type=float, default=30.0, help="training seconds of each profile (default 30)")
    p.add_argument("--only", default=None, help="comma separated labels (before, after) or task names to run")
    p.add_argument("--sizes", action="store_true", help="also the env step and SAC update at several sizes")
    p.add_argument("--runs", default="pushbox_sac,pusht_sac,obstacles_sac,b0_ppo", help="paper runs of --sizes")
    p.add_argument("--num-envs", default="1024,2048,4096", help="world counts of --sizes")
    p.add_argument("--batches", default="2048,4096,8192", help="SAC batch sizes of --sizes")
    p.add_argument("--steps", type=int, default=10, help="env steps timed per size (--sizes)")
    p.add_argument("--smoke", action="store_true", help="tiny CPU runs of a few seconds: a check, not a figure")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    import tempfile

    import warp as wp

    import magwarp  # noqa: F401 - registers the env ids

    if args.device is None:
        args.device = "cuda:0" if torch.cuda.is_available() and not args.smoke else "cpu"
    if args.smoke:
        args.seconds = min(args.seconds, 4.0)
    wp.config.quiet = True
    torch.set_float32_matmul_precision("high")  # as the training scripts on CUDA
    info = machine_info(args.device)
    print(header_line(info))
    result = {"machine": info, "phases": [], "env": [], "update": []}
    only = None if args.only is None else {x.strip() for x in args.only.split(",")}
    with tempfile.TemporaryDirectory() as tmp:
        for i, (task, label, run_name, options) in enumerate(PROFILES):
            if only is not None and label not in only and task not in only:
                continue
            row = {"task": task, "config": label, "options": " ".join(options),
                   **phase_profile(run_name, options, args.device, args.seconds, args.smoke, f"{tmp}/{i}")}
            result["phases"].append(row)
    print_table(result["phases"], [("task", "task"), ("config", "config"), ("env_steps_per_s", "env-steps/s"),
                                   *((f"{k}_pct", f"{k} %") for k in PHASES), ("options", "options")])
    if args.sizes:
        sizes(args, result)
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2))
    return 0


def sizes(args, result: dict) -> None:
    """The env step at several world counts and the SAC update at several batch sizes (sizes the presets)."""
    from magwarp.training.paper import PAPER_RUNS

    print("| run | worlds | env step (ms) | env-steps/s |\n|---|---|---|---|")
    for name in args.runs.split(","):
        run = PAPER_RUNS[name]
        for n in (int(x) for x in args.num_envs.split(",")):
            ms = env_step_ms(run.env_id, run.train_kwargs, n, args.device, args.steps)
            result["env"].append({"run": name, "num_envs": n, "step_ms": ms, "env_steps_per_s": 1000 * n / ms})
            print(f"| {name} | {n} | {ms:.2f} | {1000 * n / ms:,.0f} |", flush=True)
    from magwarp.training import sac_her as sac
    graphs = ("off", "on") if args.device.startswith("cuda") else ("off",)
    print("\n| batch | CUDA graph | ms per update |\n|---|---|---|")
    for batch in (int(x) for x in args.batches.split(",")):
        for graph in graphs:
            ms = update_ms(sac, batch, graph, args.device)
            result["update"].append({"batch": batch, "cuda_graph": graph, "update_ms": ms})
            print(f"| {batch} | {graph} | {ms:.3f} |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
