"""Tracking of mover targets at the policy rate (torch, batched): the 6D platform's IK controller.

:func:`track_movers` turns target mover poses (from :func:`magwarp.magbots.kinematics.platform_ik`) into the
per-step x/y and yaw accelerations that :class:`magwarp.physics.MjwBackend` takes with ``ControlParams(rotation=
True)``: a damped spring per axis, ``a = kp (target - pos) + kd (target_vel - vel)``, the yaw error wrapped to
(-pi, pi]. The
command is held for a whole env step (``num_cycles`` ms), so the default gains (natural frequency ~6 rad/s, damping
ratio ~1) are chosen for the 25 Hz policy rate; the backend then applies its documented acceleration and speed limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from magwarp.magbots.common import positive_fields
from magwarp.magbots.kinematics import wrap_to_pi

__all__ = ["TrackingGains", "track_movers"]


@dataclass(frozen=True)
class TrackingGains:
    """Spring and damper gains: ``kp``/``kd`` for x/y (1/s^2, 1/s), ``kp_yaw``/``kd_yaw`` for the yaw."""

    kp: float = 40.0
    kd: float = 12.0
    kp_yaw: float = 40.0
    kd_yaw: float = 12.0

    def __post_init__(self):
        positive_fields(self, ("kp", "kd", "kp_yaw", "kd_yaw"), error=ValueError, allow_zero=True)


def track_movers(pos: torch.Tensor, vel: torch.Tensor, target: torch.Tensor, gains: TrackingGains = TrackingGains(),
                 target_vel: torch.Tensor | None = None) -> torch.Tensor:
    """Accelerations ``[..., 3]`` (ax, ay, a_yaw) from mover ``pos`` ``[..., 3]`` (x, y, yaw), ``vel`` ``[..., 3]``
    (vx, vy, yaw rate) and ``target`` ``[..., 3]`` (x, y, yaw; the yaw need not be wrapped); ``target_vel`` (the
    target's rates, default 0) makes the damper act on the velocity error: ``a = kp e + kd (target_vel - vel)``."""
    e = target - pos
    e = torch.cat([e[..., :2], wrap_to_pi(e[..., 2:])], -1)
    dv = -vel if target_vel is None else target_vel - vel
    # python scalars only: no host-to-device copy per call
    xy = gains.kp * e[..., :2] + gains.kd * dv[..., :2]
    yaw = gains.kp_yaw * e[..., 2:] + gains.kd_yaw * dv[..., 2:]
    return torch.cat([xy, yaw], -1)
