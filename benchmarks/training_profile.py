"""Where a training step's time goes, per paper run: the env step at several world counts, and the SAC update
(one minibatch) eager and as a replayed CUDA graph at several batch sizes. Sizes the training presets.

    python benchmarks/training_profile.py --device cuda:0 --json training_profile.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from common import header_line, machine_info


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


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda:0")
    p.add_argument("--runs", default="pushbox_sac,pusht_sac,obstacles_sac,b0_ppo")
    p.add_argument("--num-envs", default="1024,2048,4096")
    p.add_argument("--batches", default="2048,4096,8192")
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    import warp as wp

    import magwarp  # noqa: F401 - registers the env ids
    from magwarp.training.paper import PAPER_RUNS

    wp.config.quiet = True
    torch.set_float32_matmul_precision("high")  # as the training scripts on CUDA
    info = machine_info(args.device)
    print(header_line(info))
    result = {"machine": info, "env": [], "update": []}
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
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
