"""Scripted baseline for :class:`magwarp.envs.platform_pose.PlatformPoseEnv`: a carrot in platform space plus the IK.

The policy keeps a carrot pose per env (set to the measured platform pose when an episode starts) and moves it
toward the goal by at most ``carrot_step`` per env step (x, y, z, roll, pitch, yaw; the yaw the short way round).
In ``action_mode="mover"`` the carrot is mapped through the IK to mover targets and tracked
(:func:`magwarp.magbots.control.track_movers`, with the carrot's rate and acceleration as feed-forward); in
``action_mode="pose"`` the carrot is the commanded target, sent as a pose increment. Moving the carrot in platform
space (not the movers straight to their goal positions) keeps the mover distance inside its limits while the
platform turns, so the movers never cross.
"""

from __future__ import annotations

import torch

from magwarp.magbots.control import track_movers
from magwarp.magbots.kinematics import platform_ik, wrap_to_pi

__all__ = ["PlatformIKPolicy"]


def _delta(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a - b`` for poses ``[..., 6]``, the yaw difference wrapped."""
    d = a - b
    return torch.cat([d[..., :5], wrap_to_pi(d[..., 5:])], -1)


class PlatformIKPolicy:
    """``policy(obs=None) -> action [num_envs, 6]`` for a :class:`~magwarp.envs.platform_pose.PlatformPoseEnv`."""

    def __init__(self, env, carrot_step: tuple[float, ...] = (0.04, 0.04, 0.01, 0.03, 0.03, 0.08)):
        self.env = env
        self.carrot_step = torch.as_tensor(carrot_step, dtype=torch.float32, device=env.device)
        if self.carrot_step.shape != (6,) or not bool((self.carrot_step > 0).all()):
            raise ValueError(f"carrot_step must be six positive numbers, got {carrot_step!r}")
        self.carrot = env.platform_pose().clone()
        self.rate = torch.zeros(env.num_envs, 2, 3, device=env.device)
        self.high = torch.as_tensor(env.single_action_space.high, device=env.device)

    def __call__(self, obs=None) -> torch.Tensor:
        env = self.env
        fresh = (env.num_steps == 0)[:, None]
        if env.action_mode == "pose":
            self.carrot = torch.where(fresh, env.target_pose, self.carrot)
        else:
            self.carrot = torch.where(fresh, env.platform_pose(), self.carrot)
        step = torch.maximum(torch.minimum(_delta(env.goal_pose, self.carrot), self.carrot_step), -self.carrot_step)
        previous = self.carrot
        self.carrot = previous + step
        if env.action_mode == "pose":
            return torch.clamp(_delta(self.carrot, env.target_pose) / env.pose_step, -1.0, 1.0)
        g = env.geometry
        movers = platform_ik(self.carrot, env.mover_z, g, check=False)[..., [0, 1, 3]]
        before = platform_ik(previous, env.mover_z, g, check=False)[..., [0, 1, 3]]
        period = env.backend.control.num_cycles * env.backend.dt
        rate = (movers - before) / period
        # the carrot's acceleration as feed-forward (the centripetal part keeps the spread while the platform turns)
        feed = (rate - torch.where(fresh[..., None], rate, self.rate)) / period
        self.rate = rate
        pos, vel = env.mover_state()
        act = (track_movers(pos, vel, movers, env.gains, target_vel=rate) + feed).reshape(env.num_envs, 6)
        return torch.maximum(torch.minimum(act, self.high), -self.high)
