"""Throughput of the levitation envs (``magwarp/Levitation-v0`` and its task variants): env-steps per second against
num_envs, with random actions (the env alone) and with the PD baseline (policy, commutation and env), and each task's
cost over the hover task at the same size (``x_hover``: the swinging payload's cycle hooks, the rigid payload's
per-world body rows, the moving reference's torch work).

    python benchmarks/levitation_tasks.py                                  # cpu (+ cuda:0 when present), default sizes
    python benchmarks/levitation_tasks.py --device cuda:0 --num-envs 1024,16384,131072 --json out.json

One env step is ``num_cycles`` (4) control cycles of 250 us: 1 ms. Autoreset is on and included; ``check_inputs`` is
off (a device sync per step on a GPU). Timings are medians of 5 chunks after 3 warm-up steps.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from common import finish, start_run  # noqa: E402

IDS = ("Levitation-v0", "LevitationHover-v0", "LevitationLiftoff-v0", "LevitationTrack-v0", "LevitationMove-v0",
       "LevitationPayload-v0", "LevitationPendulum-v0")


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize(device)


def step_ms(env, act, steps: int, device: str) -> float:
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        obs = env.step(act(obs))[0]
    _sync(device)
    chunk, samples = max(1, steps // 5), []
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(chunk):
            obs = env.step(act(obs))[0]
        _sync(device)
        samples.append((time.perf_counter() - t) / chunk)
    return float(np.median(samples) * 1e3)


def rows_for(env_id: str, num_envs: int, device: str, steps: int) -> list[dict]:
    import gymnasium as gym

    import magwarp  # noqa: F401  (registers the ids)

    env = gym.make_vec(f"magwarp/{env_id}", num_envs=num_envs, device=device, check_inputs=False).unwrapped
    space = env.single_action_space
    gen = torch.Generator(device=env.device).manual_seed(0)
    bank = (2 * torch.rand((8, num_envs, *space.shape), generator=gen, device=env.device) - 1) * 0.05
    count = [0]

    def random(obs):
        count[0] += 1
        return bank[count[0] % 8]

    out = []
    for policy, act in (("random", random), ("baseline", env.scripted_policy())):
        ms = step_ms(env, act, steps, device)
        out.append({"env": env_id, "device": device, "num_envs": num_envs, "policy": policy, "step_ms": ms,
                    "env_steps_per_s": num_envs / (ms / 1e3)})
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", "--devices", default=None, help="cpu or cuda:N (default: cpu, and cuda:0 if present)")
    p.add_argument("--num-envs", default=None, help="comma-separated sizes (default: 64,1024 on CPU; 1024,16384,"
                                                     "131072 on a GPU)")
    p.add_argument("--envs", default=",".join(IDS), help="comma-separated ids (without magwarp/)")
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    info, devices = start_run(args.device)
    if args.device and "," in args.device:
        devices = args.device.split(",")
    rows = []
    for device in devices:
        sizes = args.num_envs or ("64,1024" if device == "cpu" else "1024,16384,131072")
        for n in (int(s) for s in sizes.split(",")):
            hover = {}
            for env_id in args.envs.split(","):
                for row in rows_for(env_id, n, device, args.steps):
                    if env_id == "LevitationHover-v0":
                        hover[row["policy"]] = row["step_ms"]
                    base = hover.get(row["policy"])
                    row["x_hover"] = row["step_ms"] / base if base else float("nan")
                    rows.append(row)
                    print(f"{device} {n:>7} {env_id:<24} {row['policy']:<8} {row['step_ms']:8.3f} ms", flush=True)
    return finish(rows, ["env", "device", "num_envs", "policy", "step_ms", "env_steps_per_s", "x_hover"], info,
                  args.json)


if __name__ == "__main__":
    sys.exit(main())
