"""Exact, batched goal coverage for objects made of rectangles (T, L, X, boxes) or a disc (cylinder).

``coverage = area(object ∩ goal) / area(goal)`` where object and goal are the same shape at two planar poses.
The parts of a shape are disjoint (T/L/X parts only share edges), so

    area(A ∩ G) = sum_i sum_j area(a_i ∩ g_j)

exactly, with no inclusion-exclusion. Each ``a_i ∩ g_j`` is two convex quadrilaterals: ``a_i``'s corners are
expressed in ``g_j``'s frame, where ``g_j`` is the axis-aligned box ``[-hx, hx] x [-hy, hy]``, and clipped by its
four half-planes (Sutherland-Hodgman, at most 8 vertices); the shoelace formula gives the area. Discs use the
closed-form lens area. One Warp thread per pose pair; float32, so coverage is exact up to ~1e-6.

Poses are rigid motions about the body origin (the physical object). MagBotSim's shapely code rotates about the
bounding-box centre instead, which differs for the L shape (its bounding box is not centred on the body origin).
"""

from __future__ import annotations

import numpy as np
import torch
import warp as wp

from magwarp._streams import torch_stream
__all__ = ["ShapeTable", "coverage", "shape_parts"]

vec8 = wp.types.vector(length=8, dtype=float)


@wp.func
def _clip_half_plane(xs: vec8, ys: vec8, n: int, axis: int, s: float, bound: float):
    """Keep the part of polygon (xs, ys, n) where ``s * coord <= bound`` (coord = x if axis == 0 else y)."""
    ox = vec8()
    oy = vec8()
    m = int(0)
    for i in range(n):
        j = (i + 1) % n
        ci = s * wp.where(axis == 0, xs[i], ys[i]) - bound
        cj = s * wp.where(axis == 0, xs[j], ys[j]) - bound
        if ci <= 0.0:
            ox[m] = xs[i]
            oy[m] = ys[i]
            m += 1
        if (ci <= 0.0) != (cj <= 0.0):
            t = ci / (ci - cj)
            ox[m] = xs[i] + t * (xs[j] - xs[i])
            oy[m] = ys[i] + t * (ys[j] - ys[i])
            m += 1
    return ox, oy, m


@wp.func
def _rect_overlap(a: wp.vec4, pa: wp.vec3, g: wp.vec4, pg: wp.vec3) -> float:
    """Area of the intersection of part ``a`` (cx, cy, hx, hy) at pose ``pa`` (x, y, yaw) and part ``g`` at ``pg``."""
    ca = wp.cos(pa[2])
    sa = wp.sin(pa[2])
    cg = wp.cos(pg[2])
    sg = wp.sin(pg[2])
    # part centres and axes in the world
    ax = pa[0] + ca * a[0] - sa * a[1]
    ay = pa[1] + sa * a[0] + ca * a[1]
    gx = pg[0] + cg * g[0] - sg * g[1]
    gy = pg[1] + sg * g[0] + cg * g[1]
    # a's corners in g's frame (rotation by yaw_a - yaw_g, translation by the rotated centre offset)
    dc = ca * cg + sa * sg  # cos(yaw_a - yaw_g)
    ds = sa * cg - ca * sg  # sin(yaw_a - yaw_g)
    ox = cg * (ax - gx) + sg * (ay - gy)
    oy = -sg * (ax - gx) + cg * (ay - gy)
    xs = vec8()
    ys = vec8()
    for k in range(4):
        u = wp.where(k == 0 or k == 3, a[2], -a[2])
        v = wp.where(k < 2, a[3], -a[3])
        xs[k] = ox + dc * u - ds * v
        ys[k] = oy + ds * u + dc * v
    n = int(4)
    xs, ys, n = _clip_half_plane(xs, ys, n, 0, 1.0, g[2])
    xs, ys, n = _clip_half_plane(xs, ys, n, 0, -1.0, g[2])
    xs, ys, n = _clip_half_plane(xs, ys, n, 1, 1.0, g[3])
    xs, ys, n = _clip_half_plane(xs, ys, n, 1, -1.0, g[3])
    area = float(0.0)
    for i in range(n):
        j = (i + 1) % n
        area += xs[i] * ys[j] - xs[j] * ys[i]
    return 0.5 * wp.abs(area)


@wp.func
def _disc_overlap(r: float, pa: wp.vec3, pg: wp.vec3) -> float:
    """Area of the lens of two discs of radius ``r`` whose centres are at ``pa`` and ``pg``."""
    d = wp.length(wp.vec2(pa[0] - pg[0], pa[1] - pg[1]))
    if d >= 2.0 * r:
        return 0.0
    return 2.0 * r * r * wp.acos(d / (2.0 * r)) - 0.5 * d * wp.sqrt(wp.max(4.0 * r * r - d * d, 0.0))


@wp.func
def shape_overlap(parts: wp.array2d[wp.vec4], radius: wp.array[float], s: int, pa: wp.vec3, pg: wp.vec3) -> float:
    """Area of shape ``s`` at pose ``pa`` intersected with itself at pose ``pg`` (zero-size parts are padding)."""
    area = float(0.0)
    if radius[s] > 0.0:
        area = _disc_overlap(radius[s], pa, pg)
    else:
        for a in range(parts.shape[1]):
            if parts[s, a][2] > 0.0:
                for g in range(parts.shape[1]):
                    if parts[s, g][2] > 0.0:
                        area += _rect_overlap(parts[s, a], pa, parts[s, g], pg)
    return area


@wp.kernel
def coverage_kernel(
    # Model:
    parts: wp.array2d[wp.vec4],
    radius: wp.array[float],
    goal_area: wp.array[float],
    shape_index: wp.array[int],
    # State in:
    achieved: wp.array[wp.vec3],
    desired: wp.array[wp.vec3],
    # State out:
    cover: wp.array[float],
):
    i = wp.tid()
    s = shape_index[i % shape_index.shape[0]]
    cover[i] = wp.clamp(shape_overlap(parts, radius, s, achieved[i], desired[i]) / goal_area[s], 0.0, 1.0)


def shape_parts(obj) -> tuple[np.ndarray, float, float]:
    """``(parts [K, 4], radius, area)`` of an :class:`magwarp.mjcf.ObjectSpec` (radius 0 unless a cylinder)."""
    if obj.shape == "cylinder":
        return np.zeros((0, 4), dtype=np.float32), float(obj.radius), obj.area
    return obj.rects().astype(np.float32), 0.0, obj.area


class ShapeTable:
    """Object shapes as device arrays, so coverage can use a different shape per world: ``parts`` ``[S, P]``
    (rectangles ``(cx, cy, hx, hy)``, padded with zero-size parts), ``radius`` ``[S]`` (discs; 0 otherwise) and
    ``area`` ``[S]``. Built from :class:`magwarp.mjcf.ObjectSpec` s (e.g. the size variants of one object)."""

    def __init__(self, objects, device):
        rows = [shape_parts(o) for o in objects]
        if not rows:
            raise ValueError("ShapeTable needs at least one object")
        width = max(1, max(len(p) for p, _, _ in rows))
        parts = np.zeros((len(rows), width, 4), np.float32)
        for k, (p, _, _) in enumerate(rows):
            parts[k, : len(p)] = p
        dev = wp.get_device(device)
        self.num_shapes = len(rows)
        self.parts = wp.array(parts, dtype=wp.vec4, device=dev)
        self.radius = wp.array(np.array([r for _, r, _ in rows], np.float32), dtype=float, device=dev)
        self.area = wp.array(np.array([a for _, _, a in rows], np.float32), dtype=float, device=dev)
        self.zero_index = wp.zeros(1, dtype=int, device=dev)


def _pose3(name: str, pose: torch.Tensor) -> torch.Tensor:
    """Accept ``[..., 3]`` (x, y, yaw) or ``[..., 4]`` (x, y, sin yaw, cos yaw; MagBotSim's goal encoding)."""
    if not isinstance(pose, torch.Tensor) or not pose.is_floating_point():
        raise ValueError(f"{name} must be a floating-point torch.Tensor, got {type(pose).__name__}")
    if pose.shape[-1] == 4:
        pose = torch.stack([pose[..., 0], pose[..., 1], torch.atan2(pose[..., 2], pose[..., 3])], dim=-1)
    elif pose.shape[-1] != 3:
        raise ValueError(f"{name} must have last dimension 3 (x, y, yaw) or 4 (x, y, sin, cos), got {tuple(pose.shape)}")
    return pose.to(torch.float32).reshape(-1, 3).contiguous()


def coverage(achieved: torch.Tensor, desired: torch.Tensor, obj, shape_index: torch.Tensor | None = None) -> torch.Tensor:
    """Coverage of the goal pose ``desired`` by the object at ``achieved`` for every pose pair (any batch shape).

    ``obj`` is an :class:`magwarp.mjcf.ObjectSpec`, or a :class:`ShapeTable` with ``shape_index`` (int tensor of the
    batch shape, or of one element) naming each pair's shape. Returns a float32 tensor of the batch shape on the
    poses' device.
    """
    if achieved.shape[:-1] != desired.shape[:-1]:
        raise ValueError(f"achieved {tuple(achieved.shape)} and desired {tuple(desired.shape)} batch shapes differ")
    batch = achieved.shape[:-1]
    a = _pose3("achieved", achieved)
    g = _pose3("desired", desired).to(a.device)
    wp.init()
    device = wp.device_from_torch(a.device)
    table = obj if isinstance(obj, ShapeTable) else ShapeTable([obj], device)
    if shape_index is None:
        index = table.zero_index
    else:
        idx = torch.as_tensor(shape_index, device=a.device).to(torch.int32).reshape(-1).contiguous()
        if idx.numel() not in (1, a.shape[0]):
            raise ValueError(f"shape_index must have 1 or {a.shape[0]} elements, got {idx.numel()}")
        index = wp.from_torch(idx)
    out = torch.empty(a.shape[0], dtype=torch.float32, device=a.device)
    if a.shape[0]:
        stream = torch_stream(a.device) if a.device.type == "cuda" else None
        wp.launch(coverage_kernel, dim=a.shape[0],
                  inputs=[table.parts, table.radius, table.area, index, wp.from_torch(a, dtype=wp.vec3),
                          wp.from_torch(g, dtype=wp.vec3)],
                  outputs=[wp.from_torch(out)], device=device, stream=stream)
    return out.reshape(batch)
