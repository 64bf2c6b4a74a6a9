"""Push env throughput against raw mujoco-warp stepping of the same model (for benchmarks/env_throughput.py).

Run: python examples/push_throughput.py [--device cuda:0] [--tasks PushBox PushT] [--num-envs 1 64 1024] [--reps 5]
For each task and batch size: env-steps/s of ``env.step`` (40 cycles: mover control + mujoco-warp step + per-cycle
checks, all one graph, plus the torch task code), and the time of 40 bare ``mujoco_warp.step`` calls replayed as
one graph on the same model and state, with their ratio (the issue's target: at most 1.3). Medians of ``--reps``.
"""

import argparse
import time

import numpy as np
import torch
import warp as wp

from magwarp.envs.push import PushBoxEnv, PushLEnv, PushTEnv, PushWithObstaclesEnv, PushXEnv

TASKS = {"PushBox": PushBoxEnv, "PushT": PushTEnv, "PushL": PushLEnv, "PushX": PushXEnv,
         "PushWithObstacles": PushWithObstaclesEnv}


def _sync(device):
    if str(device).startswith("cuda"):
        torch.cuda.synchronize(device)


def measure(cls, num_envs: int, device: str, reps: int, steps: int) -> tuple[float, float]:
    import mujoco_warp as mjw

    env = cls(num_envs, device=device, seed=0)
    gen = torch.Generator(device=env.device).manual_seed(0)
    action = (torch.rand(num_envs, env.single_action_space.shape[0], generator=gen, device=env.device) * 4 - 2)
    for _ in range(3):  # compile, record graphs
        env.step(action)
    b = env.backend
    with wp.ScopedDevice(b.device), b._on_stream():
        with wp.ScopedCapture(device=b.device, stream=b._stream, force_module_load=False) as cap:
            for _ in range(b.control.num_cycles):
                mjw.step(b.model, b.data)
    env_t, raw_t = [], []
    for _ in range(reps):
        _sync(env.device)
        t = time.perf_counter()
        for _ in range(steps):
            env.step(action)
        _sync(env.device)
        env_t.append((time.perf_counter() - t) / steps)
        t = time.perf_counter()
        with b._on_stream():
            for _ in range(steps):
                wp.capture_launch(cap.graph)
        _sync(env.device)
        raw_t.append((time.perf_counter() - t) / steps)
    return float(np.median(env_t)), float(np.median(raw_t))


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--device", default=None)
    p.add_argument("--tasks", nargs="+", default=["PushBox", "PushT"], choices=sorted(TASKS))
    p.add_argument("--num-envs", nargs="+", type=int, default=[1, 16, 64])
    p.add_argument("--reps", type=int, default=5)
    p.add_argument("--steps", type=int, default=10)
    args = p.parse_args()
    print(f"{'task':18s} {'num_envs':>8s} {'env.step ms':>12s} {'env-steps/s':>12s} {'raw mjw ms':>11s} {'ratio':>6s}")
    for task in args.tasks:
        for n in args.num_envs:
            env_s, raw_s = measure(TASKS[task], n, args.device, args.reps, args.steps)
            print(f"{task:18s} {n:8d} {env_s * 1e3:12.2f} {n / env_s:12,.0f} {raw_s * 1e3:11.2f} {env_s / raw_s:6.2f}")


if __name__ == "__main__":
    main()
