"""Tutorial: write your own batched RL env on top of :class:`magwarp.envs.MagwarpVecEnv` ("parking").

A research-specific task in a few dozen lines: every mover must drive to its own parking slot (the tile centres of
the layout's last column; the mover with the k-th smallest start y gets the k-th slot) and come to rest there. An episode succeeds when all movers are parked (within
``tolerance`` of their slot and slower than ``rest_speed``), ends on any collision, and is cut after ``max_steps``.

What a task writes (the base class does the rest: input checks, autoreset in the same step with ``final_obs`` in
``info``, partial resets by mask, seeding, the gymnasium ``VectorEnv`` API, and every adapter):

1. ``__init__``: build a :class:`~magwarp.sim.Simulator` for ``num_envs`` worlds, call ``super().__init__``, declare
   the single-env spaces with ``_set_spaces`` and call ``reset()``.
2. ``_reset_envs(mask)``: new episodes where ``mask`` is true: write start poses, reset those worlds, reset counters.
   Use ``torch.where`` on the mask, never a Python loop over envs, and draw randomness from ``self._generator``.
3. ``_apply_action(action)``: the checked ``[num_envs, A]`` action -> ``sim.step(cycles, command)``.
4. ``_get_obs()``: the observation tensor(s) ``[num_envs, ...]``.
5. ``_evaluate(obs)``: ``reward, terminated, truncated, info`` as ``[num_envs]`` tensors.

Everything stays on the simulator's device, batched: the same code runs 4 worlds on a laptop CPU or a million on a GPU.

    python examples/custom_env_tutorial.py                       # 256 worlds, 150 steps, a PD controller
    python examples/custom_env_tutorial.py --envs 8 --steps 20 --device cpu
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch

from magwarp.envs import MagwarpVecEnv
from magwarp.envs.sampling import PoseSampler
from magwarp.layout import benchmark_layout
from magwarp.sim import Simulator, default_device


class ParkingEnv(MagwarpVecEnv):
    """Park every mover at its own slot. Observation per world: for each mover, its offset to its slot (2) and its
    velocity (2). Action: x/y accelerations of all movers. Reward: minus the summed distance to the slots, +10 on
    success, -10 on a collision."""

    def __init__(self, num_envs: int = 64, layout: str = "B0", *, max_steps: int = 150, tolerance: float = 0.02,
                 rest_speed: float = 0.05, device: str | None = None, seed: int | None = None, **kwargs):
        tiles, num_movers = benchmark_layout(layout)
        self.sim = Simulator(tiles, num_movers, num_envs, device=device or default_device(), check_inputs=False)
        super().__init__(num_envs, self.sim.torch_device, seed=seed, **kwargs)
        self.num_movers, self.max_steps = num_movers, max_steps
        self.tolerance, self.rest_speed = tolerance, rest_speed
        # the slots, ordered by y; each episode gives the mover with the k-th smallest start y the k-th slot
        self.slot_xy = torch.tensor(tiles.tile_centers()[-num_movers:], dtype=torch.float32, device=self.device)
        self.slots = self.slot_xy.expand(num_envs, num_movers, 2).clone()  # [num_envs, M, 2]
        self.sampler = PoseSampler(self.sim, 0.0, self._generator)  # valid, collision-free start configurations
        self.steps = torch.zeros(num_envs, dtype=torch.int64, device=self.device)
        obs_space = gym.spaces.Box(-np.inf, np.inf, (num_movers * 4,), np.float32)
        self._set_spaces(obs_space, gym.spaces.Box(-10.0, 10.0, (num_movers * 2,), np.float32))
        self.reset()

    def _reset_envs(self, mask):
        start = self.sim.start_pos  # [num_envs, M, 3], on the device
        new = self.sampler.sample_starts(self.num_envs)  # [num_envs, M, 2]
        start[..., :2] = torch.where(mask[:, None, None], new, start[..., :2])
        rank = new[..., 1].argsort(dim=1).argsort(dim=1)  # rank of each mover's start y in its world
        self.slots = torch.where(mask[:, None, None], self.slot_xy[rank], self.slots)
        self.sim.reset(mask)
        self.steps.masked_fill_(mask, 0)

    def _apply_action(self, action):
        self.sim.step(40, action.view(self.num_envs, self.num_movers, 2))  # 40 cycles of 1 ms, like MagBotSim
        self.steps += 1

    def _get_obs(self):
        offset = self.sim.pos[..., :2] - self.slots
        return torch.cat([offset, self.sim.vel[..., :2]], dim=-1).reshape(self.num_envs, -1)

    def _evaluate(self, obs):
        dist = (self.sim.pos[..., :2] - self.slots).norm(dim=-1)  # [num_envs, M]
        parked = (dist < self.tolerance) & (self.sim.vel[..., :2].norm(dim=-1) < self.rest_speed)
        success = parked.all(dim=1)
        collision = (self.sim.flags_any != 0).any(dim=1)  # mover-mover or wall, any cycle of the step
        reward = -dist.sum(dim=1) + 10.0 * success - 10.0 * collision
        info = {"success": success, "collision": collision, "parked": parked.sum(dim=1)}
        return reward, success | collision, self.steps >= self.max_steps, info


def pd_policy(obs: torch.Tensor, num_movers: int, kp: float = 6.0, kd: float = 5.0) -> torch.Tensor:
    """A hand-written controller: accelerate toward the slot, damp the velocity (norm-clipped by the simulator)."""
    o = obs.view(obs.shape[0], num_movers, 4)
    return (-kp * o[..., :2] - kd * o[..., 2:]).reshape(obs.shape[0], -1)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--layout", default="B0")
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)

    env = ParkingEnv(args.envs, args.layout, device=args.device, seed=0)
    obs, _ = env.reset(seed=0)
    successes = collisions = timeouts = 0
    t0 = time.perf_counter()
    for _ in range(args.steps):
        obs, reward, terminated, truncated, info = env.step(pd_policy(obs, env.num_movers))
        successes += int(info["success"].sum())
        collisions += int(info["collision"].sum())
        timeouts += int((truncated & ~terminated).sum())
    elapsed = time.perf_counter() - t0
    # the naive controller drives straight at the slots, so movers often meet on the way: room for a learned policy
    stats = dict(episodes=successes + collisions + timeouts, successes=successes, collisions=collisions,
                 timeouts=timeouts, env_steps_per_s=args.envs * args.steps / elapsed)
    print(f"{args.envs} worlds x {args.steps} steps on {env.device}: {stats['episodes']} episodes, "
          f"{successes} parked, {collisions} collided, {timeouts} timed out; "
          f"{stats['env_steps_per_s']:,.0f} env-steps/s")
    return stats


if __name__ == "__main__":
    main()
