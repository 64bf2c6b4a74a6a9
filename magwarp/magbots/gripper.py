"""A two-mover gripper MagBot: the movers' distance opens and closes a jaw through two slider-rocker linkages.

Geometry (magwarp's design; lengths in metres; frame of mover A: origin at its centre, x axis toward mover B, z up):

- Mover A carries the gripper base; mover B rides on the base's rail (the x axis) ``d`` ahead of A, so the gripper's
  yaw is the direction A -> B and its x, y are A's.
- Each jaw finger (index ``+`` and ``-``, mirrored in y) turns about a vertical hinge at
  ``(-hinge_back, +-hinge_side)``.
  A lever of length ``lever`` on the finger, at angle ``theta`` from the -x axis (toward +-y), is pulled by a rod of
  length ``rod`` pinned to the slider (mover B) at ``(d, +-pin_side)``. Closing the loop,
  ``(u + lever cos theta)^2 + (v - lever sin theta)^2 = rod^2`` with ``u = d + hinge_back``, ``v = pin_side -
  hinge_side``: spreading the movers swings the lever and opens the jaw.
- The finger extends ``finger`` from its hinge at angle ``theta - bend`` from the -x axis; the jaw width (between the
  fingertips' inner edges) is ``2 (hinge_side + finger sin(theta - bend)) - 2 pad``.

:func:`jaw_width` (distance -> width) and :func:`mover_distance` (width -> distance) are batched torch functions,
exact inverses of each other on ``[min_distance, max_distance]``; :func:`gripper_limit_violations` names the limit a
request breaks. :func:`generate_gripper_mjcf` builds the mechanism for mujoco-warp (hinges, slides, ``connect``
loop closures); :class:`GripperJoints` writes and reads its joints.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from magwarp.layout import Layout, MoverSpec
from magwarp.magbots.common import mechanism_mjcf, positive_fields
from magwarp.magbots.geometry import MagBotLimitError
from magwarp.magbots.joints import MechanismJoints
from magwarp.mjcf import XmlHooks

__all__ = ["GripperGeometry", "GripperJoints", "generate_gripper_mjcf", "gripper_limit_violations", "jaw_width",
           "lever_angle", "mover_distance"]


@dataclass(frozen=True)
class GripperGeometry:
    """Link lengths and limits of the two-mover gripper (see the module docstring)."""

    hinge_back: float = 0.05
    hinge_side: float = 0.02
    pin_side: float = 0.02
    lever: float = 0.035
    rod: float = 0.325
    finger: float = 0.08
    bend: float = 0.95
    pad: float = 0.005
    hinge_height: float = 0.03
    min_distance: float = 0.25
    max_distance: float = 0.30

    def __post_init__(self):
        positive_fields(self, ("hinge_back", "hinge_side", "lever", "rod", "finger", "pad", "hinge_height",
                               "min_distance", "max_distance"))
        for name in ("pin_side", "bend"):
            v = float(getattr(self, name))
            if not math.isfinite(v):
                raise MagBotLimitError(f"GripperGeometry.{name} must be finite, got {v!r}")
            object.__setattr__(self, name, v)
        if not self.min_distance < self.max_distance:
            raise MagBotLimitError(f"GripperGeometry.min_distance ({self.min_distance}) must be below max_distance "
                                   f"({self.max_distance})")
        d = torch.linspace(self.min_distance, self.max_distance, 33, dtype=torch.float64)
        th = lever_angle(d, self)
        if not bool(torch.isfinite(th).all()) or not bool(((th > 0) & (th < math.pi)).all()):
            raise MagBotLimitError(f"GripperGeometry: the rod ({self.rod}) cannot close the loop over the distances "
                                   f"[{self.min_distance}, {self.max_distance}] (lever angles {th.tolist()})")
        w = jaw_width(d, self)
        if not bool((w[1:] > w[:-1]).all()) or float(w.min()) < 0:
            raise MagBotLimitError(f"GripperGeometry: the jaw must open from a width >= 0 as the movers spread, got "
                                   f"{w.tolist()} at distances {d.tolist()}")

    @property
    def width_range(self) -> tuple[float, float]:
        """(closed, open) jaw widths, at ``min_distance`` and ``max_distance``."""
        w = jaw_width(torch.tensor([self.min_distance, self.max_distance], dtype=torch.float64), self)
        return float(w[0]), float(w[1])


def lever_angle(distance: torch.Tensor, g: GripperGeometry) -> torch.Tensor:
    """Lever angle ``theta`` (rad, from the -x axis) at mover distance ``distance`` (closed loop, upper branch)."""
    u = distance + g.hinge_back
    v = g.pin_side - g.hinge_side
    k = (g.rod**2 - u * u - v * v - g.lever**2) / (2 * g.lever)
    # u cos(theta) - v sin(theta) = k  <=>  R cos(theta + phi) = k
    return torch.acos(k / torch.sqrt(u * u + v * v)) - torch.atan2(torch.full_like(u, v), u)


def jaw_width(distance: torch.Tensor, g: GripperGeometry) -> torch.Tensor:
    """Jaw width (m) between the finger pads at mover distance ``distance`` (any shape)."""
    return 2 * (g.hinge_side + g.finger * torch.sin(lever_angle(distance, g) - g.bend)) - 2 * g.pad


def mover_distance(width: torch.Tensor, g: GripperGeometry) -> torch.Tensor:
    """Mover distance that opens the jaw to ``width`` (the inverse of :func:`jaw_width` on its range)."""
    theta = torch.asin((0.5 * (width + 2 * g.pad) - g.hinge_side) / g.finger) + g.bend
    v = g.pin_side - g.hinge_side
    c = g.lever
    # u^2 + 2 c cos(theta) u + (v^2 + c^2 - 2 c v sin(theta) - rod^2) = 0, positive root
    q = v * v + c * c - 2 * c * v * torch.sin(theta) - g.rod**2
    u = -c * torch.cos(theta) + torch.sqrt((c * torch.cos(theta)) ** 2 - q)
    return u - g.hinge_back


def gripper_limit_violations(width: torch.Tensor, g: GripperGeometry) -> dict[str, torch.Tensor]:
    """Per limit, where a requested jaw ``width`` breaks it: ``width_min`` (closer than fully closed),
    ``width_max`` (wider than fully open), ``non_finite``."""
    lo, hi = g.width_range
    return {"non_finite": ~torch.isfinite(width), "width_min": width < lo, "width_max": width > hi}


# Joints of one gripper, in qpos order (all 1-dof); {i} is the gripper index.
_JOINTS = ("base_x", "base_y", "base_z", "base_yaw", "slider", "rod_p", "rod_m", "finger_p", "finger_m")


def _f(x) -> str:
    return format(float(x), ".10g")


def _quat_z(angle: float) -> str:
    return f"{_f(math.cos(0.5 * angle))} 0 0 {_f(math.sin(0.5 * angle))}"


def _rod_direction(distance: torch.Tensor, g: GripperGeometry) -> torch.Tensor:
    """Angle (rad, from +x) of the + rod from its slider pin to the + lever point."""
    th = lever_angle(distance, g)
    lx, ly = -g.hinge_back - g.lever * torch.cos(th), g.hinge_side + g.lever * torch.sin(th)
    return torch.atan2(ly - g.pin_side, lx - distance)


def _inertial(mass: float, pos: str = "0 0 0") -> str:
    i = _f(mass * 1e-4)
    return f'<inertial pos="{pos}" mass="{_f(mass)}" diaginertia="{i} {i} {i}"/>'


def gripper_hooks(i: int, xy: Sequence[float], mover_z: float, g: GripperGeometry) -> XmlHooks:
    """Worldbody and equality XML of gripper ``i`` (movers ``2i`` = A, ``2i+1`` = B): model pose yaw 0, mover A at
    ``xy``, the movers at mid distance."""
    d0 = 0.5 * (g.min_distance + g.max_distance)
    t = torch.tensor([d0], dtype=torch.float64)
    th0, gam0 = float(lever_angle(t, g)), float(_rod_direction(t, g))
    alpha0 = th0 - g.bend
    hz, p = g.hinge_height, f"g{i}_"
    vis = 'contype="0" conaffinity="0" group="1"'
    body = [
        f'<body name="{p}base" pos="{_f(xy[0])} {_f(xy[1])} {_f(mover_z)}" gravcomp="1">', _inertial(0.05),
        f'<joint name="{p}base_x" type="slide" axis="1 0 0"/><joint name="{p}base_y" type="slide" axis="0 1 0"/>',
        f'<joint name="{p}base_z" type="slide" axis="0 0 1"/><joint name="{p}base_yaw" type="hinge" axis="0 0 1"/>',
        f'<geom type="box" size="0.03 0.04 0.005" pos="{_f(-0.5 * g.hinge_back)} 0 {_f(hz)}" rgba="0.2 0.2 0.2 1" '
        f'{vis}/>',
        f'<body name="{p}slider" pos="{_f(d0)} 0 0" gravcomp="1">', _inertial(0.05),
        f'<joint name="{p}slider" type="slide" axis="1 0 0"/>',
    ]
    for side, sign in (("p", 1.0), ("m", -1.0)):
        body += [
            f'<body name="{p}rod_{side}" pos="0 {_f(sign * g.pin_side)} {_f(hz)}" quat="{_quat_z(sign * gam0)}" '
            'gravcomp="1">', _inertial(0.01, f"{_f(0.5 * g.rod)} 0 0"),
            f'<joint name="{p}rod_{side}" type="hinge" axis="0 0 1"/>',
            f'<geom type="capsule" fromto="0 0 0 {_f(g.rod)} 0 0" size="0.003" rgba="0.6 0.6 0.6 1" {vis}/></body>',
        ]
    body.append("</body>")
    eq = [f'<connect name="{p}carry_a" body1="mover_{2 * i}" body2="{p}base" anchor="0 0 0"/>',
          f'<connect name="{p}carry_b" body1="mover_{2 * i + 1}" body2="{p}slider" anchor="0 0 0"/>']
    for side, sign in (("p", 1.0), ("m", -1.0)):
        lever = (-g.lever * math.cos(th0), sign * g.lever * math.sin(th0))
        tip = (-g.finger * math.cos(alpha0), sign * g.finger * math.sin(alpha0))
        body += [
            f'<body name="{p}finger_{side}" pos="{_f(-g.hinge_back)} {_f(sign * g.hinge_side)} {_f(hz)}" gravcomp="1">',
            _inertial(0.02, f"{_f(0.5 * tip[0])} {_f(0.5 * tip[1])} 0"),
            # + finger: theta grows clockwise (axis -z); - finger mirrored
            f'<joint name="{p}finger_{side}" type="hinge" axis="0 0 {_f(-sign)}"/>',
            f'<geom type="capsule" fromto="0 0 0 {_f(lever[0])} {_f(lever[1])} 0" size="0.004" rgba="0.1 0.5 0.8 1" '
            f'{vis}/>',
            f'<geom type="capsule" fromto="0 0 0 {_f(tip[0])} {_f(tip[1])} 0" size="0.004" rgba="0.1 0.5 0.8 1" '
            f'{vis}/>',
            f'<geom name="{p}pad_{side}" type="sphere" size="{_f(g.pad)}" pos="{_f(tip[0])} {_f(tip[1])} 0" '
            'rgba="0.9 0.3 0.1 1"/>',
            "</body>",
        ]
        eq.append(f'<connect name="{p}close_{side}" body1="{p}rod_{side}" body2="{p}finger_{side}" '
                  f'anchor="{_f(g.rod)} 0 0"/>')
    body.append("</body>")
    return XmlHooks(worldbody="\n".join(body), equality="\n".join(eq))


def generate_gripper_mjcf(layout: Layout, gripper_xy: Sequence[Sequence[float]], *,
                          geometry: GripperGeometry | None = None, mover: MoverSpec | None = None,
                          hooks: XmlHooks | Mapping[str, object] | None = None, **mjcf_options) -> str:
    """MJCF with one gripper per row of ``gripper_xy`` (``[G, 2]``: mover A's model position); gripper ``i`` uses
    movers ``2i`` (A) and ``2i+1`` (B, mid distance ahead along +x). Options pass to :func:`generate_mjcf`. The
    finger pads collide (MuJoCo's default contype), the rest of the mechanism is visual."""
    g = geometry or GripperGeometry()
    d0 = 0.5 * (g.min_distance + g.max_distance)

    def movers(xy: np.ndarray, mover_z: float) -> np.ndarray:
        return np.stack([xy, xy + np.array([d0, 0.0])], 1).reshape(-1, 2)

    return mechanism_mjcf(layout, gripper_xy, "gripper", mover, hooks, movers,
                          lambda i, xy, mover_z: gripper_hooks(i, xy, mover_z, g), **mjcf_options)


class GripperJoints:
    """qpos addresses of the grippers of a compiled model, and batched state <-> qpos maps (torch).

    A gripper state is ``(x, y, yaw, width)``: mover A's position, the direction A -> B and the jaw width."""

    def __init__(self, mjm: mujoco.MjModel, geometry: GripperGeometry | None = None):
        self.geometry = g = geometry or GripperGeometry()
        self.map = m = MechanismJoints(mjm, "g", _JOINTS, "gripper")
        self.num_grippers = m.count
        self.qpos_adr, self.mover_qpos_adr, self.base_pos0 = m.qpos_adr, m.mover_qpos_adr, m.base_pos0
        self.d0 = 0.5 * (g.min_distance + g.max_distance)
        t = torch.tensor([self.d0], dtype=torch.float64)
        self.theta0, self.gamma0 = float(lever_angle(t, g)), float(_rod_direction(t, g))

    def state(self, qpos: torch.Tensor) -> torch.Tensor:
        """Gripper states ``[W, G, 4]`` (x, y, yaw, jaw width) from ``qpos`` ``[W, nq]`` (through the joints)."""
        g = self.geometry
        q = self.map.gather(qpos)
        b0 = self.map.on("base_pos0", qpos, qpos.dtype)
        theta = self.theta0 + q[..., _JOINTS.index("finger_p")]
        width = 2 * (g.hinge_side + g.finger * torch.sin(theta - g.bend)) - 2 * g.pad
        return torch.stack([b0[:, 0] + q[..., 0], b0[:, 1] + q[..., 1], q[..., 3], width], -1)

    def write_qpos(self, qpos: torch.Tensor, state: torch.Tensor, mover_z, *, check: bool = True) -> None:
        """Write gripper states ``[W, G, 4]`` (x, y, yaw, width) into ``qpos`` ``[W, nq]`` in place: the mechanism's
        joints and both movers' free joints (level, yaw 0). ``check`` refuses widths outside the jaw's range."""
        g = self.geometry
        W, G = qpos.shape[0], self.num_grippers
        if tuple(state.shape) != (W, G, 4):
            raise MagBotLimitError(f"state must have shape ({W}, {G}, 4), got {tuple(state.shape)}")
        state = state.to(qpos.dtype)
        if check:
            for name, bad in gripper_limit_violations(state[..., 3].double(), g).items():
                if bool(bad.any()):
                    idx = tuple(int(v) for v in torch.nonzero(bad)[0])
                    lo, hi = g.width_range
                    raise MagBotLimitError(f"jaw width {float(state[idx][3]):.6g} at index {idx} violates limit "
                                           f"{name!r} (range [{lo:.6g}, {hi:.6g}])")
        d = mover_distance(state[..., 3].double(), g).to(qpos.dtype)
        theta = lever_angle(d.double(), g).to(qpos.dtype)
        gam = _rod_direction(d.double(), g).to(qpos.dtype)
        b0 = self.map.on("base_pos0", qpos, qpos.dtype)
        zm = torch.as_tensor(mover_z, dtype=qpos.dtype, device=qpos.device).expand(W, G)
        vals = {"base_x": state[..., 0] - b0[:, 0], "base_y": state[..., 1] - b0[:, 1], "base_z": zm - b0[:, 2],
                "base_yaw": state[..., 2], "slider": d - self.d0, "rod_p": gam - self.gamma0,
                "rod_m": -(gam - self.gamma0), "finger_p": theta - self.theta0, "finger_m": theta - self.theta0}
        self.map.scatter(qpos, vals)
        madr = self.map.on("mover_qpos_adr", qpos)
        c, s = torch.cos(state[..., 2]), torch.sin(state[..., 2])
        for side, off in ((0, 0.0), (1, 1.0)):
            base = madr[:, side]
            qpos[:, base] = state[..., 0] + off * d * c
            qpos[:, base + 1] = state[..., 1] + off * d * s
            qpos[:, base + 2] = zm
            qpos[:, base + 3] = 1.0
            for k in (4, 5, 6):
                qpos[:, base + k] = 0.0
