"""MagBots: mechanisms carried by several coupled movers (the 6D platform), batched.

- :mod:`magwarp.magbots.geometry` — documented link geometry and limits (:class:`PlatformGeometry`);
- :mod:`magwarp.magbots.kinematics` — batched torch inverse/forward kinematics and limit checks;
- :mod:`magwarp.magbots.mjcf` — MJCF of the platform mechanism through :class:`magwarp.mjcf.XmlHooks`;
- :mod:`magwarp.magbots.control` — tracking of IK mover targets at the policy rate;
- :mod:`magwarp.magbots.gripper` — a two-mover gripper (jaw kinematics, MJCF, joint maps).
"""

from __future__ import annotations

from magwarp.magbots.geometry import MagBotLimitError, PlatformGeometry
from magwarp.magbots.kinematics import check_platform_pose, platform_fk, platform_ik, platform_limit_violations

__all__ = [
    "MagBotLimitError",
    "PlatformGeometry",
    "check_platform_pose",
    "platform_fk",
    "platform_ik",
    "platform_limit_violations",
]
