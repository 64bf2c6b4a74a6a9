"""MJCF of 6D-platform MagBots carried by pairs of movers, through :class:`magwarp.mjcf.XmlHooks`.

The mechanism of platform ``i`` (movers ``mover_{2i}`` = A and ``mover_{2i+1}`` = B; geometry of
:class:`~magwarp.magbots.geometry.PlatformGeometry`) is a world-rooted tree closed by equality constraints, using only
joints and constraints that mujoco-warp supports (slide/hinge joints, ``weld``, ``connect``, ``joint`` equality):

- ``p{i}_base``: slide x, y, z and hinge (yaw) joints; the frame between the movers at the movers' centre height,
  x axis from A to B;
- ``p{i}_rail_a`` / ``p{i}_rail_b``: slide along the base's x axis (the mover distance), symmetric about the base
  (a joint equality keeps the base at the movers' midpoint); each carries a turntable
  ``p{i}_plate_a`` / ``_b`` (hinge z) welded to its mover, so the turntable angle is the mover's yaw relative to the
  platform;
- ``p{i}_link_a`` / ``_b``: lifting links (length L) hinged on the rails ``hinge_height`` above the mover centre,
  kept symmetric by a joint equality; ``p{i}_lift`` hangs on link A's tip and is closed onto link B's tip by a
  ``connect`` (its hinges are ``2 a`` apart), so it stays level at ``z_mover + hinge_height + L sin(theta)``;
- ``p{i}_platform``: the platform, its origin (site ``p{i}_platform_site``) at the top centre, ``lift_offset -
  hinge_height`` above the lift, with a pitch then a roll hinge (orientation ``Rz(yaw) Ry(pitch) Rx(roll)``), each
  tied to its turntable by the gear ratio through a joint equality (``roll = -gear_a * plate_a``).

Unlike MagBotSim's model, the tilt centre is the platform's top centre, so the IK of
:mod:`magwarp.magbots.kinematics` is exact for this model (MagBotSim tilts about a ball joint below the top and
corrects the tilt with a Python P-controller every cycle). The mechanism's geoms are visual only (contype 0):
the platform carries no contacts here, and mover-mover collision stays geometric. All bodies are gravity
compensated, as MagBotSim's are.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from magwarp.layout import Layout, LayoutError, MoverSpec
from magwarp.magbots.common import mechanism_mjcf, positive_fields
from magwarp.magbots.geometry import MagBotLimitError, PlatformGeometry
from magwarp.magbots.joints import MechanismJoints
from magwarp.magbots.kinematics import check_platform_pose, platform_ik
from magwarp.mjcf import XmlHooks

__all__ = ["PlatformJoints", "PlatformModelSpec", "generate_platform_mjcf", "platform_hooks"]

# Joints of one platform, in qpos order (all 1-dof); {i} is the platform index.
_JOINTS = ("base_x", "base_y", "base_z", "base_yaw", "rail_a", "plate_a", "link_a", "lift", "pitch", "roll",
           "rail_b", "plate_b", "link_b")


def _f(x) -> str:
    return format(float(x), ".10g")


@dataclass(frozen=True)
class PlatformModelSpec:
    """Masses and visual sizes of the platform mechanism (the kinematics live in :class:`PlatformGeometry`).

    ``hinge_height``: height of the links' rail hinges above the mover centre. ``platform_half_size``: half extents
    of the platform plate (x, y, z). Masses in kg; MagBotSim's parts total about 0.75 kg. ``plate_friction``:
    ``None`` keeps the plate visual only (no contacts, the default); a number makes the plate a contact geom (named
    ``p{i}_plate``, MuJoCo's default contact bits, that sliding friction) that carries objects, e.g. a product.
    """

    hinge_height: float = 0.03
    platform_half_size: tuple[float, float, float] = (0.08, 0.08, 0.004)
    base_mass: float = 0.01
    rail_mass: float = 0.1
    plate_mass: float = 0.05
    link_mass: float = 0.02
    lift_mass: float = 0.1
    platform_mass: float = 0.2
    plate_friction: float | None = None

    def __post_init__(self):
        positive_fields(self, ("hinge_height", "base_mass", "rail_mass", "plate_mass", "link_mass", "lift_mass",
                               "platform_mass"))
        if self.plate_friction is not None:
            positive_fields(self, ("plate_friction",))
        hs = tuple(float(v) for v in self.platform_half_size)
        if len(hs) != 3 or not all(math.isfinite(v) and v > 0 for v in hs):
            raise MagBotLimitError(f"PlatformModelSpec.platform_half_size must be three positive numbers, got {hs!r}")
        object.__setattr__(self, "platform_half_size", hs)


def _box_inertia(mass: float, half: tuple[float, float, float]) -> str:
    hx, hy, hz = half
    return (f'<inertial pos="0 0 0" mass="{_f(mass)}" diaginertia="{_f(mass * (hy * hy + hz * hz) / 3)} '
            f'{_f(mass * (hx * hx + hz * hz) / 3)} {_f(mass * (hx * hx + hy * hy) / 3)}"/>')


def platform_hooks(i: int, xy: Sequence[float], mover_z: float, geometry: PlatformGeometry, spec: PlatformModelSpec,
                   num_movers: int) -> XmlHooks:
    """Worldbody and equality XML of platform ``i`` (movers ``2i``, ``2i+1``), its model pose level, yaw 0, at ``xy``
    and the middle of its height range, the movers' centres at ``mover_z``."""
    g, s = geometry, spec
    lo, hi = g.height_range
    h0 = 0.5 * (lo + hi) - g.lift_offset  # lift above z_mover + lift_offset at the model pose
    theta0 = math.asin(h0 / g.link_length)
    half0 = g.link_offset + g.link_length * math.cos(theta0)
    L, a, hz = g.link_length, g.link_offset, s.hinge_height
    p = f"p{i}_"
    gv = 'contype="0" conaffinity="0" group="1"'
    plate = f'<geom type="cylinder" size="0.05 0.004" rgba="0.2 0.2 0.2 1" {gv}/>'
    link_geom = (f'<geom type="capsule" fromto="0 0 0 {_f(L)} 0 0" size="0.006" rgba="0.1 0.6 0.2 1" {gv}/>')
    hx, hy, hzp = s.platform_half_size
    plate_contact = gv if s.plate_friction is None else (
        f'name="{p}plate" friction="{_f(s.plate_friction)} 0.005 0.0001" group="1"')
    body = [
        f'<body name="{p}base" pos="{_f(xy[0])} {_f(xy[1])} {_f(mover_z)}" gravcomp="1">',
        _box_inertia(s.base_mass, (0.02, 0.02, 0.02)),
        f'<joint name="{p}base_x" type="slide" axis="1 0 0"/><joint name="{p}base_y" type="slide" axis="0 1 0"/>',
        f'<joint name="{p}base_z" type="slide" axis="0 0 1"/><joint name="{p}base_yaw" type="hinge" axis="0 0 1"/>',
    ]
    for side, sign in (("a", -1.0), ("b", 1.0)):
        # link a points inward (+x) and up; link b is turned by pi about z, so the same hinge angle lowers both
        link_quat = (f"{_f(math.cos(-theta0 / 2))} 0 {_f(math.sin(-theta0 / 2))} 0" if side == "a"
                     else f"0 {_f(-math.sin(-theta0 / 2))} 0 {_f(math.cos(-theta0 / 2))}")
        body += [
            f'<body name="{p}rail_{side}" pos="{_f(sign * half0)} 0 0" gravcomp="1">',
            _box_inertia(s.rail_mass, (0.03, 0.03, 0.01)),
            f'<joint name="{p}rail_{side}" type="slide" axis="1 0 0"/>',
            f'<geom type="box" size="0.03 0.03 0.01" pos="0 0 {_f(0.5 * hz)}" rgba="0.1 0.1 0.1 1" {gv}/>',
            f'<body name="{p}plate_{side}" gravcomp="1">',
            _box_inertia(s.plate_mass, (0.05, 0.05, 0.004)),
            f'<joint name="{p}plate_{side}" type="hinge" axis="0 0 1"/>{plate}</body>',
            f'<body name="{p}link_{side}" pos="0 0 {_f(hz)}" quat="{link_quat}" gravcomp="1">',
            _box_inertia(s.link_mass, (0.5 * L, 0.006, 0.006)).replace('pos="0 0 0"', f'pos="{_f(0.5 * L)} 0 0"'),
            f'<joint name="{p}link_{side}" type="hinge" axis="0 1 0"/>{link_geom}',
        ]
        if side == "a":
            body += [
                f'<body name="{p}lift" pos="{_f(L)} 0 0" '
                f'quat="{_f(math.cos(theta0 / 2))} 0 {_f(math.sin(theta0 / 2))} 0" gravcomp="1">',
                _box_inertia(s.lift_mass, (a, 0.03, 0.005)).replace('pos="0 0 0"', f'pos="{_f(a)} 0 0"'),
                f'<joint name="{p}lift" type="hinge" axis="0 1 0"/>',
                f'<geom type="box" size="{_f(a)} 0.03 0.005" pos="{_f(a)} 0 0" rgba="0.3 0.3 0.3 1" {gv}/>',
                f'<body name="{p}platform" pos="{_f(a)} 0 {_f(g.lift_offset - hz)}" gravcomp="1">',
                _box_inertia(s.platform_mass, (hx, hy, hzp)),
                f'<joint name="{p}pitch" type="hinge" axis="0 1 0"/><joint name="{p}roll" type="hinge" axis="1 0 0"/>',
                f'<geom type="box" size="{_f(hx)} {_f(hy)} {_f(hzp)}" pos="0 0 {_f(-hzp)}" '
                f'rgba="0.15 0.15 0.15 1" {plate_contact}/>',
                f'<site name="{p}platform_site" size="0.004" rgba="1 0 0 1"/>',
                "</body></body>",
            ]
        body += ["</body></body>"]
    body.append("</body>")
    ma, mb = f"mover_{2 * i}", f"mover_{2 * i + 1}"
    eq = [
        f'<weld name="{p}weld_a" body1="{ma}" body2="{p}plate_a" relpose="0 0 0 1 0 0 0"/>',
        f'<weld name="{p}weld_b" body1="{mb}" body2="{p}plate_b" relpose="0 0 0 1 0 0 0"/>',
        f'<connect name="{p}close" body1="{p}link_b" body2="{p}lift" anchor="{_f(L)} 0 0"/>',
        f'<joint name="{p}rails" joint1="{p}rail_b" joint2="{p}rail_a" polycoef="0 -1 0 0 0"/>',
        f'<joint name="{p}links" joint1="{p}link_b" joint2="{p}link_a" polycoef="0 1 0 0 0"/>',
        f'<joint name="{p}gear_a" joint1="{p}roll" joint2="{p}plate_a" polycoef="0 {_f(-g.gear_a)} 0 0 0"/>',
        f'<joint name="{p}gear_b" joint1="{p}pitch" joint2="{p}plate_b" polycoef="0 {_f(-g.gear_b)} 0 0 0"/>',
    ]
    if 2 * i + 1 >= num_movers:
        raise LayoutError(f"platform {i} needs movers {2 * i} and {2 * i + 1}, but the model has {num_movers} movers")
    return XmlHooks(worldbody="\n".join(body), equality="\n".join(eq))


def generate_platform_mjcf(
    layout: Layout,
    platform_xy: Sequence[Sequence[float]],
    *,
    geometry: PlatformGeometry | None = None,
    spec: PlatformModelSpec | None = None,
    mover: MoverSpec | None = None,
    hooks: XmlHooks | Mapping[str, object] | None = None,
    **mjcf_options,
) -> str:
    """MJCF with one 6D platform per row of ``platform_xy`` (``[P, 2]``), each carried by two movers.

    Platform ``i`` uses movers ``2i`` (A, -x side) and ``2i+1`` (B); its model pose is level, yaw 0, at mid height.
    Start poses per world are set without a rebuild through :class:`PlatformJoints`. ``hooks`` (user XML) and
    ``mjcf_options`` (e.g. ``timestep``, ``solver``, ``objects``) pass through to :func:`magwarp.mjcf.generate_mjcf`.
    """
    g = geometry or PlatformGeometry()
    s = spec or PlatformModelSpec()
    lo, hi = g.height_range

    def movers(xy: np.ndarray, mover_z: float) -> np.ndarray:
        pose = torch.zeros(len(xy), 6, dtype=torch.float64)
        pose[:, :2] = torch.as_tensor(xy)
        pose[:, 2] = mover_z + 0.5 * (lo + hi)
        return platform_ik(pose, mover_z, g).numpy()[:, :, :2].reshape(-1, 2)

    return mechanism_mjcf(layout, platform_xy, "platform", mover, hooks, movers,
                          lambda i, xy, mover_z: platform_hooks(i, xy, mover_z, g, s, 2 * len(platform_xy)),
                          **mjcf_options)


class PlatformJoints:
    """Where the platforms' joints live in ``qpos`` of a compiled model, and batched pose <-> qpos maps (torch).

    :meth:`pose` reads platform poses ``[W, P, 6]`` from ``qpos`` ``[W, nq]`` through the joints (exact, no
    site kinematics needed); :meth:`write_qpos` writes the mechanism's and the movers' qpos for given platform poses
    (the IK, every joint of the tree, and the movers' free joints), e.g. into a backend's ``init_qpos`` before a reset.
    """

    def __init__(self, mjm: mujoco.MjModel, geometry: PlatformGeometry | None = None,
                 spec: PlatformModelSpec | None = None):
        self.geometry = g = geometry or PlatformGeometry()
        self.spec = spec or PlatformModelSpec()
        self.map = m = MechanismJoints(mjm, "p", _JOINTS, "6D platform")
        self.num_platforms = m.count
        self.qpos_adr, self.mover_qpos_adr, self.base_pos0 = m.qpos_adr, m.mover_qpos_adr, m.base_pos0
        lo, hi = g.height_range
        self.theta0 = math.asin((0.5 * (lo + hi) - g.lift_offset) / g.link_length)
        self.half0 = g.link_offset + g.link_length * math.cos(self.theta0)

    def pose(self, qpos: torch.Tensor) -> torch.Tensor:
        """Platform poses ``[W, P, 6]`` (x, y, z, roll, pitch, yaw of the top centre) from ``qpos`` ``[W, nq]``."""
        g = self.geometry
        q = self.map.gather(qpos)  # [W, P, 13]
        b0 = self.map.on("base_pos0", qpos, qpos.dtype)
        theta = self.theta0 - q[..., _JOINTS.index("link_a")]
        z = b0[:, 2] + q[..., 2] + g.lift_offset + g.link_length * torch.sin(theta)
        return torch.stack([b0[:, 0] + q[..., 0], b0[:, 1] + q[..., 1], z, q[..., _JOINTS.index("roll")],
                            q[..., _JOINTS.index("pitch")], q[..., 3]], -1)

    def write_qpos(self, qpos: torch.Tensor, pose: torch.Tensor, mover_z, *, check: bool = True) -> None:
        """Write platform poses ``pose`` ``[W, P, 6]`` into ``qpos`` ``[W, nq]`` in place: every joint of the
        mechanism and the two movers' free joints (level, yaw from the IK). ``check`` refuses poses outside the
        limits (:class:`MagBotLimitError` naming the limit)."""
        g = self.geometry
        W, P = qpos.shape[0], self.num_platforms
        if tuple(pose.shape) != (W, P, 6):
            raise MagBotLimitError(f"pose must have shape ({W}, {P}, 6), got {tuple(pose.shape)}")
        pose = pose.to(qpos.dtype)
        if check:
            check_platform_pose(pose, mover_z, g)
        movers = platform_ik(pose, mover_z, g, check=False)  # [W, P, 2, 4]
        b0 = self.map.on("base_pos0", qpos, qpos.dtype)
        half = 0.5 * torch.linalg.norm(movers[..., 1, :2] - movers[..., 0, :2], dim=-1)
        h = pose[..., 2] - movers[..., 0, 2] - g.lift_offset
        theta = torch.asin(h / g.link_length)
        rel_a = movers[..., 0, 3] - pose[..., 5]
        rel_b = movers[..., 1, 3] - pose[..., 5]
        vals = {
            "base_x": pose[..., 0] - b0[:, 0], "base_y": pose[..., 1] - b0[:, 1],
            "base_z": movers[..., 0, 2] - b0[:, 2],
            "base_yaw": pose[..., 5], "rail_a": -(half - self.half0), "rail_b": half - self.half0,
            "plate_a": rel_a, "plate_b": rel_b, "link_a": self.theta0 - theta, "link_b": self.theta0 - theta,
            "lift": theta - self.theta0, "pitch": pose[..., 4], "roll": pose[..., 3],
        }
        self.map.scatter(qpos, vals)
        madr = self.map.on("mover_qpos_adr", qpos)
        for side in range(2):
            m = movers[..., side, :]
            base = madr[:, side]
            for c in range(3):
                qpos[:, base + c] = m[..., c]
            half_yaw = 0.5 * m[..., 3]
            qpos[:, base + 3] = torch.cos(half_yaw)
            qpos[:, base + 4] = 0.0
            qpos[:, base + 5] = 0.0
            qpos[:, base + 6] = torch.sin(half_yaw)
