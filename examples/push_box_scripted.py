"""Batched Push-Box on mujoco-warp with a scripted pushing policy written as torch ops on the whole batch.

Run: python examples/push_box_scripted.py [--num-envs 64] [--steps 100] [--device cpu]
Prints env-steps/s and how many episodes reached the goal. The policy (no learning, no Python loop over envs):
get behind the box on the far side from the goal (going around it when in front), then push towards the goal;
a PD law on position turns targets into acceleration commands. It is a demo of the API, not a good controller.
"""

import argparse
import time

import torch

from magwarp.envs.push import PushBoxEnv


def scripted_policy(obs: dict[str, torch.Tensor], k: float = 60.0, d: float = 15.0, off: float = 0.15) -> torch.Tensor:
    mover, vel = obs["observation"][:, :2], obs["observation"][:, 2:4]
    box, goal = obs["achieved_goal"], obs["desired_goal"]
    u = torch.nn.functional.normalize(goal - box, dim=1)  # push direction
    behind = box - off * u
    rel = mover - box
    in_front = (rel * u).sum(1, keepdim=True) > -0.05
    side = torch.stack([-u[:, 1], u[:, 0]], 1)
    side = side * torch.sign((rel * side).sum(1, keepdim=True) + 1e-6)
    waypoint = torch.where(in_front, box + 0.2 * side - 0.1 * u, behind)  # around the box, not through it
    aligned = (mover - behind).norm(dim=1, keepdim=True) < 0.03
    target = torch.where(aligned, goal - (off - 0.02) * u, waypoint)
    return (k * (target - mover) - d * vel).clamp(-10.0, 10.0)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--num-envs", type=int, default=64)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--device", default=None)
    args = p.parse_args()
    env = PushBoxEnv(args.num_envs, device=args.device, seed=0)
    obs, _ = env.reset()
    reached = torch.zeros(args.num_envs, dtype=torch.bool, device=env.device)
    episodes = successes = 0
    t0 = time.perf_counter()
    for _ in range(args.steps):
        obs, reward, terminated, truncated, info = env.step(scripted_policy(obs))
        reached |= info["is_success"]
        done = terminated | truncated
        episodes += int(done.sum())
        successes += int((reached & done).sum())
        reached &= ~done
    dt = time.perf_counter() - t0
    print(f"device {env.device}: {args.num_envs} envs x {args.steps} steps in {dt:.2f} s = "
          f"{args.num_envs * args.steps / dt:,.0f} env-steps/s; {episodes} episodes, {successes} reached the goal")


if __name__ == "__main__":
    main()
