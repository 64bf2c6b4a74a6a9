"""Random agents on trajectory planning, through each interface: the batched torch env, the batched multi-agent
view, the PettingZoo ParallelEnv (one agent per mover) and, when installed, the SB3, TorchRL, rsl_rl and skrl adapters.

Each section runs uniformly random actions and prints episodes finished, goals reached, collisions and env-steps/s.

    python examples/random_agents.py                       # B0, 64 worlds, 100 steps
    python examples/random_agents.py --layout B5 --envs 8 --steps 20 --device cpu
"""

from __future__ import annotations

import argparse
import importlib.util
import time

import numpy as np
import torch

from magwarp.envs import TrajectoryPlanningEnv
from magwarp.envs.adapters import MagwarpParallelEnv, MultiAgentVecEnv


def _report(name: str, steps: int, seconds: float, episodes: int, goals: int, collisions: int) -> dict:
    print(f"{name:<22} {episodes:6d} episodes {goals:6d} goals {collisions:6d} collisions {steps / seconds:12,.0f} env-steps/s")
    return dict(episodes=episodes, goals=goals, collisions=collisions)


def batched(args) -> dict:
    env = TrajectoryPlanningEnv(args.envs, args.layout, device=args.device, seed=0)
    gen = torch.Generator(device=env.device).manual_seed(0)
    env.reset(seed=0)
    high = float(env.single_action_space.high[0])
    episodes = goals = collisions = 0
    t0 = time.perf_counter()
    for _ in range(args.steps):
        action = (torch.rand(env.action_space.shape, generator=gen, device=env.device) * 2 - 1) * high
        _, _, terminated, truncated, info = env.step(action)
        episodes += int((terminated | truncated).sum())
        goals += int(info["goals_reached"].sum())
        collisions += int(terminated.sum())
    return _report("batched torch", args.envs * args.steps, time.perf_counter() - t0, episodes, goals, collisions)


def multi_agent(args) -> dict:
    ma = MultiAgentVecEnv(TrajectoryPlanningEnv(args.envs, args.layout, device=args.device, seed=0))
    ma.reset(seed=0)
    high = float(ma.single_agent_action_space.high[0])
    episodes = goals = collisions = 0
    t0 = time.perf_counter()
    for _ in range(args.steps):
        action = (torch.rand(ma.num_envs, ma.num_movers, 2, device=ma.device) * 2 - 1) * high
        obs, reward, terminated, truncated, info = ma.step(action)  # obs [envs, movers, D], reward [envs, movers]
        episodes += int((terminated | truncated)[:, 0].sum())
        goals += int(info["goals_reached"].sum())
        collisions += int(terminated[:, 0].sum())
    return _report("multi-agent torch", args.envs * args.steps, time.perf_counter() - t0, episodes, goals, collisions)


def pettingzoo(args) -> dict:
    env = MagwarpParallelEnv(layout=args.layout, device=args.device, seed=0)
    env.reset(seed=0)
    for agent in env.possible_agents:
        env.action_space(agent).seed(0)
    episodes = goals = collisions = 0
    t0 = time.perf_counter()
    for _ in range(args.steps):
        actions = {agent: env.action_space(agent).sample() for agent in env.agents}
        obs, rewards, terms, truncs, infos = env.step(actions)
        goals += sum(i["goal_reached"] for i in infos.values())
        if not env.agents:  # the episode is over for everyone
            episodes += 1
            collisions += any(terms.values())
            env.reset()
    return _report("pettingzoo (1 world)", args.steps, time.perf_counter() - t0, episodes, goals, collisions)


def sb3(args) -> dict | None:
    if importlib.util.find_spec("stable_baselines3") is None:
        print("stable-baselines3 not installed: skipping the SB3 VecEnv")
        return None
    from magwarp.envs.adapters import SB3VecEnv

    venv = SB3VecEnv(TrajectoryPlanningEnv(args.envs, args.layout, device=args.device, seed=0))
    venv.seed(0)
    venv.reset()
    venv.action_space.seed(0)
    episodes = goals = collisions = 0
    t0 = time.perf_counter()
    for _ in range(args.steps):
        actions = np.stack([venv.action_space.sample() for _ in range(venv.num_envs)])
        _, rewards, dones, infos = venv.step(actions)
        episodes += int(dones.sum())
        collisions += sum(i["mover_collision"] or i["wall_collision"] for i in infos)
        goals += int((rewards > 0).sum())  # steps with at least one goal
    return _report("sb3 VecEnv", args.envs * args.steps, time.perf_counter() - t0, episodes, goals, collisions)


def torchrl(args) -> dict | None:
    if importlib.util.find_spec("torchrl") is None:
        print("torchrl not installed: skipping the TorchRL env")
        return None
    from magwarp.envs.adapters import TorchRLEnv

    env = TorchRLEnv(TrajectoryPlanningEnv, num_envs=args.envs, layout=args.layout, device=args.device, seed=0)
    env.set_seed(0)
    t0 = time.perf_counter()
    rollout = env.rollout(args.steps, break_when_any_done=False)  # random actions from the action spec
    nxt = rollout["next"]
    return _report("torchrl EnvBase", args.envs * args.steps, time.perf_counter() - t0, int(nxt["done"].sum()),
                   int((nxt["reward"] > 0).sum()), int(nxt["terminated"].sum()))


def rsl_rl(args) -> dict | None:
    if importlib.util.find_spec("rsl_rl") is None:
        print("rsl-rl-lib not installed: skipping the rsl_rl VecEnv")
        return None
    from magwarp.envs.adapters import RslRlVecEnv

    env = RslRlVecEnv(TrajectoryPlanningEnv(args.envs, args.layout, device=args.device, seed=0))
    gen = torch.Generator(device=env.device).manual_seed(0)
    episodes = goals = collisions = 0
    t0 = time.perf_counter()
    for _ in range(args.steps):
        action = torch.rand(env.num_envs, env.num_actions, generator=gen, device=env.device) * 2 - 1  # ±1: the bound
        _, _, dones, extras = env.step(action)
        log = extras["log"]  # per-env counts of the env's boolean info flags
        episodes += int(dones.sum())
        goals += int(log["Magwarp/goals_reached"].sum())
        collisions += int(((log["Magwarp/mover_collision"] + log["Magwarp/wall_collision"]) > 0).sum())
    return _report("rsl_rl VecEnv", args.envs * args.steps, time.perf_counter() - t0, episodes, goals, collisions)


def skrl(args) -> dict | None:
    if importlib.util.find_spec("skrl") is None:
        print("skrl not installed: skipping the skrl wrapper")
        return None
    from magwarp.envs.adapters import SkrlVecEnv

    env = SkrlVecEnv(TrajectoryPlanningEnv(args.envs, args.layout, device=args.device, seed=0))
    env.reset()
    gen = torch.Generator(device=env.device).manual_seed(0)
    high = float(env.action_space.high[0])
    episodes = goals = collisions = 0
    t0 = time.perf_counter()
    for _ in range(args.steps):
        action = (torch.rand(env.num_envs, *env.action_space.shape, generator=gen, device=env.device) * 2 - 1) * high
        _, _, terminated, truncated, info = env.step(action)  # flags [envs, 1]
        episodes += int((terminated | truncated).sum())
        goals += int(info["goals_reached"].sum())
        collisions += int(terminated.sum())
    return _report("skrl wrapper", args.envs * args.steps, time.perf_counter() - t0, episodes, goals, collisions)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layout", default="B0")
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    return {f.__name__: f(args) for f in (batched, multi_agent, pettingzoo, sb3, torchrl, rsl_rl, skrl)}


if __name__ == "__main__":
    main()
