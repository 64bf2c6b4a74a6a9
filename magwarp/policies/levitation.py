"""The scripted baseline of ``magwarp/Levitation-v0``: a PD law on the 6-DoF pose through the commutation.

Wanted wrench (world frame): ``F = m (g e_z + kp (p* - p) - kd v)`` and ``tau = I (-kr e - dr omega)`` with ``e``
the small-angle rotation error (roll, pitch, yaw - yaw*), both critically damped at the natural frequency
``frequency`` (Hz); the commutation (:meth:`magwarp.magnetics.actuator.CoilActuator.commutate`: least copper loss
within the current limits, at the mover's current pose) turns it into the action's coil currents (or, with
``action="wrench"``, the wrench itself is the action).
"""

from __future__ import annotations

import math

import torch

__all__ = ["LevitationPD"]


class LevitationPD:
    """``policy(obs) -> action`` for a :class:`~magwarp.envs.levitation.LevitationEnv` (batched, on its device)."""

    def __init__(self, env, frequency: float = 15.0, damping: float = 1.0):
        self.env = getattr(env, "unwrapped", env)
        if not math.isfinite(frequency) or frequency <= 0:
            raise ValueError(f"frequency must be positive, got {frequency!r}")
        w = 2 * math.pi * frequency
        self.kp, self.kd = w * w, 2 * damping * w
        dev = self.env.device
        self.mass = float(self.env.mover.mass)
        size = self.env.mover.size  # full box sizes (m)
        m = self.mass
        self.inertia = torch.tensor([m / 12 * (size[1] ** 2 + size[2] ** 2), m / 12 * (size[0] ** 2 + size[2] ** 2),
                                     m / 12 * (size[0] ** 2 + size[1] ** 2)], device=dev)
        self.gravity = float(self.env.sim.model.limits.gravity)

    def wrench(self, obs: torch.Tensor) -> torch.Tensor:
        """The PD law's wanted wrench ``[N, 6]`` for observations ``[N, 19]``."""
        pos, rpy, vel, omega, sp = obs[:, 0:3], obs[:, 3:6], obs[:, 6:9], obs[:, 9:12], obs[:, 12:16]
        force = self.mass * (self.kp * (sp[:, :3] - pos) - self.kd * vel)
        force[:, 2] += self.mass * self.gravity
        # the small-angle rotation error in the world frame (omega and the torque are world-frame): roll and pitch
        # are about the mover's own x and y axes, turned by its yaw
        c, s = torch.cos(rpy[:, 2]), torch.sin(rpy[:, 2])
        err = torch.stack([c * rpy[:, 0] - s * rpy[:, 1], s * rpy[:, 0] + c * rpy[:, 1],
                           torch.remainder(rpy[:, 2] - sp[:, 3] + math.pi, 2 * math.pi) - math.pi], 1)
        torque = self.inertia * (-self.kp * err - self.kd * omega)
        return torch.cat([force, torque], 1)

    def __call__(self, obs: torch.Tensor) -> torch.Tensor:
        env = self.env
        wrench = self.wrench(obs)
        if env.action_mode == "wrench":
            return torch.clamp(wrench / env._scale, -1.0, 1.0)
        currents = env.actuator.commutate(wrench[:, None, :])[:, 0]
        return (currents / env.current_limit).to(torch.float32)
