"""Batched kinematics of the 6D-platform MagBot (torch; any leading batch shape, any float dtype and device).

Conventions (see :mod:`magwarp.magbots.geometry`): a platform pose is ``(x, y, z, roll, pitch, yaw)`` of the
platform's top centre, orientation ``Rz(yaw) Ry(pitch) Rx(roll)``. A mover pose is ``(x, y, z, yaw)`` of the
mover's centre (the movers stay level). Mover A (index 0) sits at ``-d/2`` along the platform's x axis and drives the
roll; mover B (index 1) at ``+d/2`` drives the pitch.

- :func:`platform_ik` — platform poses -> mover poses ``[..., 2, 4]`` (yaws not wrapped, as MagBotSim returns them);
- :func:`platform_fk` — mover poses -> platform poses (yaw wrapped to (-pi, pi]);
- :func:`platform_limit_violations` / :func:`check_platform_pose` — which limit each pose breaks, or an error that
  names it. Nothing is clamped: the IK of a pose outside the limits is computed as is (NaN where the linkage cannot
  reach), and ``check=True`` refuses it first.
"""

from __future__ import annotations

import math

import torch

from magwarp.magbots.geometry import LIMIT_NAMES, MagBotLimitError, PlatformGeometry

__all__ = ["platform_ik", "platform_fk", "platform_limit_violations", "check_platform_pose", "wrap_to_pi"]

_DEFAULT = PlatformGeometry()


def wrap_to_pi(a: torch.Tensor) -> torch.Tensor:
    """``a`` wrapped to (-pi, pi]."""
    return -torch.remainder(-a + math.pi, 2 * math.pi) + math.pi


def _as_pose(pose, name: str, width: int) -> torch.Tensor:
    if not isinstance(pose, torch.Tensor):
        raise MagBotLimitError(f"{name} must be a torch.Tensor, got {type(pose).__name__}")
    if not pose.is_floating_point():
        raise MagBotLimitError(f"{name} must be a floating-point tensor, got dtype {pose.dtype}")
    if pose.dim() < 1 or pose.shape[-1] != width:
        raise MagBotLimitError(f"{name} must have shape [..., {width}], got {tuple(pose.shape)}")
    return pose


def _mover_z(mover_z, like: torch.Tensor) -> torch.Tensor:
    if isinstance(mover_z, (int, float)):  # a fill, not a host-to-device copy (these run inside env steps)
        return torch.full(like.shape[:-1], float(mover_z), dtype=like.dtype, device=like.device)
    z = torch.as_tensor(mover_z, dtype=like.dtype, device=like.device)
    try:
        return torch.broadcast_to(z, like.shape[:-1])
    except RuntimeError as e:
        raise MagBotLimitError(
            f"mover_z of shape {tuple(z.shape)} does not broadcast to {tuple(like.shape[:-1])}") from e


def platform_limit_violations(pose: torch.Tensor, mover_z,
                              geometry: PlatformGeometry = _DEFAULT) -> dict[str, torch.Tensor]:
    """Per limit in :data:`~magwarp.magbots.geometry.LIMIT_NAMES`, a bool tensor ``[...]``: where ``pose`` breaks it.

    ``roll``/``pitch``: ``|angle| > max_tilt``; ``height_min``/``height_max``: the platform height above the movers
    needs a mover distance above ``max_mover_distance`` / below ``min_mover_distance`` (or a lift the links cannot
    reach); ``non_finite``: a NaN/inf component. No host sync.
    """
    pose = _as_pose(pose, "pose", 6)
    g = geometry
    h = pose[..., 2] - _mover_z(mover_z, pose)
    lo, hi = g.height_range
    return {
        "non_finite": ~torch.isfinite(pose).all(-1),
        "roll": pose[..., 3].abs() > g.max_tilt,
        "pitch": pose[..., 4].abs() > g.max_tilt,
        "height_min": h < lo,
        "height_max": h > hi,
    }


def check_platform_pose(pose: torch.Tensor, mover_z, geometry: PlatformGeometry = _DEFAULT) -> None:
    """Raise :class:`MagBotLimitError` naming the first broken limit, its value and the sample index (host sync)."""
    g = geometry
    lo, hi = g.height_range
    bounds = {"roll": f"|roll| <= {g.max_tilt:.6g}", "pitch": f"|pitch| <= {g.max_tilt:.6g}",
              "height_min": f"z - mover_z >= {lo:.6g}", "height_max": f"z - mover_z <= {hi:.6g}",
              "non_finite": "finite"}
    viol = platform_limit_violations(pose, mover_z, geometry)
    for name in LIMIT_NAMES:
        bad = viol[name]
        if bool(bad.any()):
            idx = tuple(int(i) for i in torch.nonzero(bad)[0])
            p = pose[idx].tolist()
            raise MagBotLimitError(
                f"platform pose {[round(v, 6) for v in p]} at index {idx} violates limit {name!r} ({bounds[name]})"
            )


def platform_ik(pose: torch.Tensor, mover_z, geometry: PlatformGeometry = _DEFAULT, *,
                check: bool = True) -> torch.Tensor:
    """Mover poses ``[..., 2, 4]`` (x, y, z, yaw of A and B) that put the platform at ``pose`` ``[..., 6]``.

    ``mover_z``: the movers' centre height (a number or a tensor broadcastable to ``pose.shape[:-1]``).
    ``check`` (default) raises :class:`MagBotLimitError` for a pose outside the limits (one host sync); with
    ``check=False`` such poses are mapped as is (NaN where the links cannot reach: see
    :func:`platform_limit_violations` to mask them without a sync).
    """
    pose = _as_pose(pose, "pose", 6)
    g = geometry
    zm = _mover_z(mover_z, pose)
    if check:
        check_platform_pose(pose, zm, g)
    x, y, z, roll, pitch, yaw = pose.unbind(-1)
    h = z - zm - g.lift_offset
    half = g.link_offset + torch.sqrt(g.link_length**2 - h * h)
    c, s = torch.cos(yaw), torch.sin(yaw)
    mover_a = torch.stack([x - half * c, y - half * s, zm, yaw - roll / g.gear_a], -1)
    mover_b = torch.stack([x + half * c, y + half * s, zm, yaw - pitch / g.gear_b], -1)
    return torch.stack([mover_a, mover_b], -2)


def platform_fk(movers: torch.Tensor, geometry: PlatformGeometry = _DEFAULT) -> torch.Tensor:
    """Platform poses ``[..., 6]`` from mover poses ``[..., 2, 4]`` (x, y, z, yaw of A and B); yaw in (-pi, pi].

    The platform height uses the movers' mean z and the upper branch of the linkage. Movers further apart than the
    links reach give NaN heights (see :func:`platform_limit_violations` on the result, or check the distance).
    """
    if not isinstance(movers, torch.Tensor) or not movers.is_floating_point():
        raise MagBotLimitError(f"movers must be a floating-point torch.Tensor, got {type(movers).__name__}")
    if movers.dim() < 2 or tuple(movers.shape[-2:]) != (2, 4):
        raise MagBotLimitError(f"movers must have shape [..., 2, 4], got {tuple(movers.shape)}")
    g = geometry
    a, b = movers[..., 0, :], movers[..., 1, :]
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    yaw = torch.atan2(dy, dx)
    s = 0.5 * torch.sqrt(dx * dx + dy * dy) - g.link_offset
    z = 0.5 * (a[..., 2] + b[..., 2]) + g.lift_offset + torch.sqrt(g.link_length**2 - s * s)
    roll = -g.gear_a * wrap_to_pi(a[..., 3] - yaw)
    pitch = -g.gear_b * wrap_to_pi(b[..., 3] - yaw)
    return torch.stack([0.5 * (a[..., 0] + b[..., 0]), 0.5 * (a[..., 1] + b[..., 1]), z, roll, pitch, yaw], -1)
