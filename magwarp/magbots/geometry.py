"""Link geometry and limits of the 6D-platform MagBot (two movers carry one platform).

The mechanism (MagBotSim's "6D-Platform MagBot" for XPlanar APM4330 movers; all lengths in metres):

- Mover A and mover B each carry a rail mount. The platform frame's x axis points from A to B, so the platform
  yaw is the direction of the line A -> B and the platform's x, y are the movers' midpoint.
- A lifting linkage: on each side, a link of length ``link_length`` (L) is hinged at the rail mount (above the
  mover's centre) and at the platform's lift body, whose two hinges are ``link_offset`` (a) from its centre. With
  the movers ``d`` apart, ``d / 2 = a + L cos(theta)`` and the platform rises ``h = L sin(theta)`` above its lowest
  reference, so ``z_platform = z_mover + lift_offset + h`` (``lift_offset`` c: the fixed heights of the rail mount,
  the hinges and the platform top). Only the upper branch (``h >= 0``) is physical.
- Tilt: each mover's yaw relative to the platform's yaw turns a gear train. Mover A's turns the platform about its
  x axis (roll), mover B's about its y axis (pitch): ``roll = -gear_a (yaw_A - yaw)``, ``pitch = -gear_b (yaw_B -
  yaw)``. The platform orientation is ``Rz(yaw) Ry(pitch) Rx(roll)``, the tilt centre at the platform's top centre.

Defaults are MagBotSim 1.3's numbers: ``d = 2 (0.091 + sqrt(0.156^2 - (z_p - z_m - 0.1278)^2))``, gear ratios
0.119 / 0.131, tilt limit 14 degrees, mover distance 0.258 .. 0.455 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MagBotLimitError", "PlatformGeometry", "LIMIT_NAMES"]

#: Names of the limits that :func:`magwarp.magbots.kinematics.platform_limit_violations` checks, in report order.
LIMIT_NAMES = ("non_finite", "roll", "pitch", "height_min", "height_max")


class MagBotLimitError(ValueError):
    """A MagBot pose or geometry outside its limits; the message names the limit, the value and the sample."""


@dataclass(frozen=True)
class PlatformGeometry:
    """Link geometry and limits of a 6D-platform MagBot (see the module docstring for the linkage).

    :param link_length: L, hinge-to-hinge length of each lifting link.
    :param link_offset: a, horizontal distance of each link's platform hinge from the platform centre.
    :param lift_offset: c, platform top height above the mover reference height when the links are horizontal.
    :param gear_a: platform roll per radian of mover A's yaw relative to the platform (sign: roll = -gear_a * dyaw).
    :param gear_b: platform pitch per radian of mover B's yaw relative to the platform.
    :param max_tilt: limit of ``|roll|`` and ``|pitch|`` (rad).
    :param min_mover_distance: smallest mover centre distance (the movers' footprints and the linkage's stop).
    :param max_mover_distance: largest mover centre distance.
    """

    link_length: float = 0.156
    link_offset: float = 0.091
    lift_offset: float = 0.1278
    gear_a: float = 0.119
    gear_b: float = 0.131
    max_tilt: float = math.radians(14.0)
    min_mover_distance: float = 0.258
    max_mover_distance: float = 0.455

    def __post_init__(self):
        for name in ("link_length", "link_offset", "gear_a", "gear_b", "max_tilt", "min_mover_distance",
                     "max_mover_distance"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v <= 0:
                raise MagBotLimitError(f"PlatformGeometry.{name} must be a positive finite number, got {v!r}")
            object.__setattr__(self, name, v)
        c = float(self.lift_offset)
        if not math.isfinite(c):
            raise MagBotLimitError(f"PlatformGeometry.lift_offset must be finite, got {c!r}")
        object.__setattr__(self, "lift_offset", c)
        if self.max_tilt >= math.pi / 2:
            raise MagBotLimitError(f"PlatformGeometry.max_tilt must be below pi/2, got {self.max_tilt!r}")
        lo, hi = self.min_mover_distance, self.max_mover_distance
        a, L = self.link_offset, self.link_length
        if not lo < hi:
            raise MagBotLimitError(
                f"PlatformGeometry.min_mover_distance ({lo}) must be below max_mover_distance ({hi})")
        if lo < 2 * a:
            raise MagBotLimitError(
                f"PlatformGeometry.min_mover_distance ({lo}) is below 2 * link_offset ({2 * a}): links past vertical"
            )
        if hi > 2 * (a + L):
            raise MagBotLimitError(
                f"PlatformGeometry.max_mover_distance ({hi}) exceeds the linkage's reach 2 * (link_offset + "
                f"link_length) = {2 * (a + L)}"
            )
        # A yaw difference of max_tilt / gear must stay within (-pi, pi) so the forward kinematics is unique.
        for name in ("gear_a", "gear_b"):
            if self.max_tilt / getattr(self, name) >= math.pi:
                raise MagBotLimitError(
                    f"PlatformGeometry.{name} ({getattr(self, name)}) is too small: max_tilt / {name} must be below pi"
                )

    def lift_height(self, mover_distance: float) -> float:
        """``h = sqrt(L^2 - (d/2 - a)^2)``: the platform's rise above ``z_mover + lift_offset`` at distance ``d``."""
        s = 0.5 * mover_distance - self.link_offset
        return math.sqrt(max(self.link_length**2 - s * s, 0.0))

    @property
    def height_range(self) -> tuple[float, float]:
        """(lowest, highest) platform height above the mover reference height (at max and min mover distance)."""
        return (self.lift_offset + self.lift_height(self.max_mover_distance),
                self.lift_offset + self.lift_height(self.min_mover_distance))

    def max_yaw_offset(self, mover: int) -> float:
        """The largest ``|yaw_mover - yaw_platform|`` within the tilt limit (mover 0 = A, 1 = B)."""
        return self.max_tilt / (self.gear_a if mover == 0 else self.gear_b)
