"""Live 3D views of magwarp scenes through Newton's viewers (``newton.viewer``).

:class:`SceneViewer` streams tiles, movers (with a translucent safety zone, red when collided), goals, objects and
obstacles to any Newton viewer as instanced boxes, cylinders and spheres. Per-frame transforms are computed from the
state arrays by Warp kernels on the viewer's device (no host loop over worlds or movers); several worlds are laid
out side by side on a grid.

Backends (:func:`make_viewer`): ``gl`` (OpenGL window, needs a display), ``viser`` (browser; bound to 127.0.0.1
unless told otherwise; needs the ``viser`` package), ``usd`` (writes a ``.usd``/``.usda`` file for Omniverse / Isaac;
needs ``usd-core``), ``rerun`` (needs ``rerun-sdk``) and ``null`` (draws nothing; for tests). Newton's ``ViewerFile``
records Newton ``Model``/``State`` objects only and ignores instances, so it is not offered here.

Example::

    viewer = SceneViewer(make_viewer("usd", path="run.usda"), layout, mover, worlds=4)
    for t in range(200):
        sim.step()
        viewer.log(sim.pos, sim.quat, flags=sim.collision, goals=goals)
    viewer.close()
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import warp as wp

from magwarp.layout import Layout, MoverSpec
from magwarp.render import colors
from magwarp.render.topdown import _pack_object_shapes

__all__ = ["SceneViewer", "make_viewer", "VIEWER_KINDS"]

VIEWER_KINDS = ("gl", "viser", "usd", "rerun", "null")

# Geometry prototypes with unit size; instances are scaled (boxes: half extents; cylinders: radius, radius, half h).
_BOX = "/magwarp/geo/box"
_CYLINDER = "/magwarp/geo/cylinder"
_SPHERE = "/magwarp/geo/sphere"

OBJECT_HALF_HEIGHT = 0.02  # drawn height of pushable objects (MagBotSim's default object half height)
OBSTACLE_HALF_HEIGHT = 0.03
ZONE_HALF_HEIGHT = wp.constant(0.001)  # the safety zone is a thin translucent disc/plate on the tile surface


def make_viewer(kind: str, *, path: str | None = None, host: str = "127.0.0.1", port: int = 8080,
                width: int = 1280, height: int = 720, headless: bool = False, num_frames: int | None = None,
                fps: float = 25.0):
    """Create a Newton viewer of ``kind`` (one of :data:`VIEWER_KINDS`) with magwarp's safe defaults.

    ``path`` is the output file for ``usd`` (required) and an optional ``.rrd`` recording for ``rerun``. ``host``
    defaults to 127.0.0.1 so the browser viewer is not exposed on the network.
    """
    if kind not in VIEWER_KINDS:
        raise ValueError(f"unknown viewer {kind!r}; choose one of {list(VIEWER_KINDS)}")
    try:
        import newton.viewer as nv
    except ImportError as e:
        raise ImportError(f"the 3D viewer needs Newton: pip install newton==1.8.0 (without its 'sim' extra) ({e})") from e
    if kind == "null":
        return nv.ViewerNull(num_frames=num_frames) if num_frames is not None else nv.ViewerNull()
    if kind == "usd":
        if not path:
            raise ValueError("the usd viewer needs an output path (e.g. run.usda)")
        try:
            import pxr  # noqa: F401
        except ImportError as e:
            raise ImportError("the usd viewer needs usd-core: pip install usd-core") from e
        return nv.ViewerUSD(output_path=path, fps=int(round(fps)), up_axis="Z", num_frames=num_frames)
    if kind == "viser":
        try:
            import viser  # noqa: F401
        except ImportError as e:
            raise ImportError("the browser viewer needs viser: pip install viser") from e
        return nv.ViewerViser(host=host, port=int(port), label="magwarp")
    if kind == "rerun":
        try:
            import rerun  # noqa: F401
        except ImportError as e:
            raise ImportError("the rerun viewer needs rerun-sdk: pip install rerun-sdk") from e
        return nv.ViewerRerun(app_id="magwarp", record_to_rrd=path)
    try:
        return nv.ViewerGL(width=width, height=height, headless=headless, num_frames=num_frames)
    except Exception as e:  # no display, no GL context: say so in one line
        raise RuntimeError(f"the OpenGL viewer could not start ({type(e).__name__}: {e}); "
                           "try --viewer viser (browser) or --viewer usd (file)") from e


# ----------------------------------------------------------------------------------------------------- kernels


@wp.func
def yaw_quat(yaw: float) -> wp.quat:
    return wp.quat(0.0, 0.0, wp.sin(0.5 * yaw), wp.cos(0.5 * yaw))


@wp.kernel
def mover_instances(
    # Model:
    cell_worlds: wp.array[wp.int32],
    offsets: wp.array[wp.vec3],
    palette: wp.array[wp.vec3],
    collision_color: wp.vec3,
    footprint_half: wp.vec3,
    hover_z: float,
    shape_kind: int,
    margin: float,
    radii: wp.array2d[wp.float32],
    half_sizes: wp.array3d[wp.float32],
    # State in:
    pos: wp.array3d[wp.float32],
    rot: wp.array3d[wp.float32],
    flags: wp.array2d[wp.int32],
    goals: wp.array3d[wp.float32],
    # State out:
    mover_xf: wp.array[wp.transform],
    mover_color: wp.array[wp.vec3],
    zone_xf: wp.array[wp.transform],
    zone_scale: wp.array[wp.vec3],
    zone_color: wp.array[wp.vec3],
    goal_xf: wp.array[wp.transform],
):
    c, m = wp.tid()
    w = cell_worlds[c]
    num_movers = pos.shape[1]
    i = c * num_movers + m
    wp_ = wp.min(w, pos.shape[0] - 1)
    z = hover_z
    if pos.shape[2] >= 3:
        z = pos[wp_, m, 2]
    p = wp.vec3(pos[wp_, m, 0], pos[wp_, m, 1], z) + offsets[c]
    wr = wp.min(w, rot.shape[0] - 1)
    q = wp.quat_identity()
    if rot.shape[2] == 4:
        q = wp.normalize(wp.quat(rot[wr, m, 0], rot[wr, m, 1], rot[wr, m, 2], rot[wr, m, 3]))
    else:
        q = yaw_quat(rot[wr, m, 0])
    mover_xf[i] = wp.transform(p, q)
    base = palette[m % palette.shape[0]]
    mover_color[i] = base
    collided = False
    if flags.shape[1] == num_movers:
        if flags[wp.min(w, flags.shape[0] - 1), m] != 0:
            collided = True
    # Safety zone: a thin plate on the tile surface, in the mover's colour, red when collided.
    zone_xf[i] = wp.transform(wp.vec3(p[0], p[1], ZONE_HALF_HEIGHT), q)
    if shape_kind == 1:
        wh = wp.min(w, half_sizes.shape[0] - 1)
        zone_scale[i] = wp.vec3(half_sizes[wh, m, 0] + margin, half_sizes[wh, m, 1] + margin, ZONE_HALF_HEIGHT)
    else:
        r = radii[wp.min(w, radii.shape[0] - 1), m] + margin
        zone_scale[i] = wp.vec3(r, r, ZONE_HALF_HEIGHT)
    zone_color[i] = base
    if collided:
        zone_color[i] = collision_color
    if goals.shape[1] == num_movers:
        wg = wp.min(w, goals.shape[0] - 1)
        goal_xf[i] = wp.transform(wp.vec3(goals[wg, m, 0], goals[wg, m, 1], hover_z) + offsets[c], wp.quat_identity())


@wp.kernel
def part_instances(
    # Model:
    cell_worlds: wp.array[wp.int32],
    offsets: wp.array[wp.vec3],
    parts: wp.array2d[wp.vec4],
    half_height: float,
    # State in:
    poses: wp.array3d[wp.float32],
    # State out:
    box_xf: wp.array[wp.transform],
    box_scale: wp.array[wp.vec3],
    disc_xf: wp.array[wp.transform],
    disc_scale: wp.array[wp.vec3],
):
    """One instance per (cell, object, part): rectangles go to the box batch, discs to the cylinder batch; the
    other batch gets a zero scale (invisible), which keeps both batches a fixed size."""
    c, o, k = wp.tid()
    w = wp.min(cell_worlds[c], poses.shape[0] - 1)
    i = (c * parts.shape[0] + o) * parts.shape[1] + k
    yaw = poses[w, o, 2]
    q = yaw_quat(yaw)
    part = parts[o, k]
    centre = wp.quat_rotate(q, wp.vec3(part[0], part[1], 0.0))
    p = wp.vec3(poses[w, o, 0], poses[w, o, 1], half_height) + centre + offsets[c]
    box_xf[i] = wp.transform(p, q)
    disc_xf[i] = wp.transform(p, q)
    box_scale[i] = wp.vec3(0.0, 0.0, 0.0)
    disc_scale[i] = wp.vec3(0.0, 0.0, 0.0)
    if part[2] > 0.0:
        if part[3] > 0.0:
            box_scale[i] = wp.vec3(part[2], part[3], half_height)
        else:
            disc_scale[i] = wp.vec3(part[2], part[2], half_height)


@wp.kernel
def obstacle_instances(
    # Model:
    cell_worlds: wp.array[wp.int32],
    offsets: wp.array[wp.vec3],
    half_height: float,
    # State in:
    obstacles: wp.array3d[wp.float32],
    # State out:
    xf: wp.array[wp.transform],
    scale: wp.array[wp.vec3],
):
    c, k = wp.tid()
    w = wp.min(cell_worlds[c], obstacles.shape[0] - 1)
    i = c * obstacles.shape[1] + k
    xf[i] = wp.transform(wp.vec3(obstacles[w, k, 0], obstacles[w, k, 1], half_height) + offsets[c],
                         yaw_quat(obstacles[w, k, 4]))
    scale[i] = wp.vec3(obstacles[w, k, 2], obstacles[w, k, 3], half_height)


# ----------------------------------------------------------------------------------------------------- streaming


class SceneViewer:
    """Streams a magwarp scene to a Newton viewer, for one world or a grid of worlds side by side.

    Args:
        viewer: a Newton viewer (see :func:`make_viewer`).
        layout, mover: the scene's layout and mover spec.
        worlds: number of worlds to show (``0..n-1``) or their indices.
        spacing: distance between world origins in metres (default: layout extent + one tile).
        object_shapes: one list of parts ``(cx, cy, hx, hy)`` per object (as for the top-down renderer).
        fps: frame rate used to time-stamp frames (USD time codes).
    """

    def __init__(self, viewer, layout: Layout, mover: MoverSpec | None = None, *, worlds: int | Sequence[int] = 1,
                 spacing: float | None = None, object_shapes=None, fps: float = 25.0):
        self.viewer = viewer
        self.layout = layout
        self.mover = mover if mover is not None else MoverSpec()
        self.device = wp.get_device(getattr(viewer, "device", None))
        cell_worlds = np.arange(int(worlds)) if np.ndim(worlds) == 0 else np.asarray(worlds, dtype=np.int64).reshape(-1)
        if len(cell_worlds) == 0 or np.any(cell_worlds < 0):
            raise ValueError(f"worlds must be a positive count or a list of world indices >= 0, got {worlds!r}")
        self.num_cells = len(cell_worlds)
        self._max_world = int(cell_worlds.max())
        self.cols = math.ceil(math.sqrt(self.num_cells))
        ex, ey = layout.extent
        step = float(spacing) if spacing is not None else max(ex, ey) + layout.tile.size
        offsets = np.zeros((self.num_cells, 3), dtype=np.float32)
        offsets[:, 0] = (np.arange(self.num_cells) % self.cols) * step
        offsets[:, 1] = -(np.arange(self.num_cells) // self.cols) * step
        self.offsets_np = offsets
        dev = self.device
        self._cell_worlds = wp.array(cell_worlds.astype(np.int32), dtype=wp.int32, device=dev)
        self._offsets = wp.array(offsets, dtype=wp.vec3, device=dev)
        self._palette = wp.array(np.asarray(colors.MOVER_PALETTE, np.float32) / 255.0, dtype=wp.vec3, device=dev)
        self._parts_np = _pack_object_shapes(object_shapes)
        self._parts = wp.array(self._parts_np, dtype=wp.vec4, device=dev)
        self.fps = float(fps)
        self.frame = 0
        self._static_logged = False
        self._buffers: dict[str, wp.array] = {}

        import newton

        self._geo = newton.GeoType
        # Prototypes are hidden (else some backends draw them, 1 m large, at the origin); instances are shown.
        viewer.log_geo(_BOX, newton.GeoType.BOX, (1.0, 1.0, 1.0), 0.0, True, hidden=True)
        viewer.log_geo(_CYLINDER, newton.GeoType.CYLINDER, (1.0, 1.0), 0.0, True, hidden=True)
        viewer.log_geo(_SPHERE, newton.GeoType.SPHERE, (1.0,), 0.0, True, hidden=True)
        self._tiles = self._tile_instances()
        self.frame_camera()

    def frame_camera(self, pitch: float = -55.0) -> None:
        """Point the viewer's camera at the whole grid of worlds, from the -y side and above (z up)."""
        ex, ey = self.layout.extent
        lo = self.offsets_np[:, :2].min(axis=0)
        hi = self.offsets_np[:, :2].max(axis=0) + (ex, ey)
        centre = 0.5 * (lo + hi)
        size = float(max(hi - lo))
        dist = 1.4 * size + 0.3
        yaw = 90.0  # looking towards +y
        front = np.array([0.0, np.cos(np.radians(pitch)), np.sin(np.radians(pitch))])
        pos = np.array([centre[0], centre[1], 0.0]) - front * dist
        try:
            self.viewer.set_camera(wp.vec3(*pos.astype(np.float32)), pitch=pitch, yaw=yaw)
        except Exception:  # noqa: BLE001 - a backend without a camera (file, null) just ignores it
            pass

    # ------------------------------------------------------------------ helpers
    def _buffer(self, name: str, n: int, dtype) -> wp.array:
        buf = self._buffers.get(name)
        if buf is None or buf.shape[0] != n:
            buf = wp.zeros(n, dtype=dtype, device=self.device)
            self._buffers[name] = buf
        return buf

    def _const(self, name: str, n: int, value, dtype) -> wp.array:
        """An array of ``n`` copies of ``value`` (cached: colours and materials that never change)."""
        key = f"{name}:{n}"
        buf = self._buffers.get(key)
        if buf is None:
            buf = wp.array(np.tile(np.asarray(value, np.float32), (n, 1)) if np.ndim(value) else np.full(n, value, np.float32),
                           dtype=dtype, device=self.device)
            self._buffers[key] = buf
        return buf

    def _tile_instances(self):
        centers = self.layout.tile_centers().astype(np.float32)
        h = self.layout.tile.half
        th = 0.5 * self.layout.tile.height
        xf = np.zeros((self.num_cells * len(centers), 7), dtype=np.float32)
        for c in range(self.num_cells):  # once, at construction
            sl = slice(c * len(centers), (c + 1) * len(centers))
            xf[sl, 0:2] = centers + self.offsets_np[c, :2]
            xf[sl, 2] = -th  # tile top surface at z = 0
            xf[sl, 6] = 1.0
        n = len(xf)
        # A 4 mm gap between tiles draws the grid.
        scale = np.tile(np.array([h - 0.002, h - 0.002, th], np.float32), (n, 1))
        color = np.tile(np.asarray(colors.TILE, np.float32) / 255.0 * 0.8, (n, 1))
        dev = self.device
        return (wp.array(xf, dtype=wp.transform, device=dev), wp.array(scale, dtype=wp.vec3, device=dev),
                wp.array(color, dtype=wp.vec3, device=dev))

    def _materials(self, n: int) -> wp.array:
        return self._const("material", n, (0.6, 0.0, 0.0, 0.0), wp.vec4)

    # ------------------------------------------------------------------ per frame
    def log(self, pos, rot=None, *, flags=None, radii=None, half_sizes=None, goals=None, object_poses=None,
            object_goals=None, obstacles=None, time: float | None = None) -> None:
        """Send one frame (same array conventions as :meth:`magwarp.render.TopDownRenderer.draw`)."""
        import torch

        from magwarp.render.arrays import as_tensor, per_world

        td = wp.device_to_torch(self.device)
        v = self.viewer
        pos_t = per_world(pos, trailing=(3,), allow_trailing=(2, 3), name="pos", device=td)
        num_worlds, num_movers = pos_t.shape[:2]
        if self._max_world >= num_worlds:
            raise ValueError(f"the viewer shows worlds up to {self._max_world}, but pos has only {num_worlds} world(s)")
        if rot is None:
            rot_t = torch.zeros((1, num_movers, 1), dtype=torch.float32, device=td)
        else:
            rot_t = as_tensor(rot, device=td, dtype=torch.float32, name="rot")
            if rot_t.ndim >= 2 and rot_t.shape[-1] == 4 and rot_t.shape[-2] == num_movers:
                rot_t = per_world(rot_t, trailing=(4,), name="rot (quaternions)", device=td, num_items=num_movers)
            else:
                rot_t = per_world(rot_t, trailing=(), name="rot (yaw)", device=td, num_items=num_movers).unsqueeze(-1)
        flags_t = (torch.zeros((1, 0), dtype=torch.int32, device=td) if flags is None else
                   per_world(flags, trailing=(), name="flags", device=td, dtype=torch.int32, num_items=num_movers))
        radii_t = (torch.full((1, num_movers), self.mover.collision_radius, dtype=torch.float32, device=td)
                   if radii is None else per_world(radii, trailing=(), name="radii", device=td, num_items=num_movers))
        half_t = (torch.tensor(self.mover.collision_half_size, dtype=torch.float32, device=td).expand(1, num_movers, 2).contiguous()
                  if half_sizes is None else per_world(half_sizes, trailing=(2,), name="half_sizes", device=td, num_items=num_movers))
        goals_t = (torch.zeros((1, 0, 2), dtype=torch.float32, device=td) if goals is None else
                   per_world(goals, trailing=(2,), name="goals", device=td, num_items=num_movers))

        t = self.frame / self.fps if time is None else float(time)
        v.begin_frame(t)
        # Static tiles: once for file backends (values persist over time), every frame for live ones.
        if not self._static_logged or not _is_file_backend(v):
            xf, sc, col = self._tiles
            v.log_instances("/magwarp/tiles", _BOX, xf, sc, col, self._materials(len(xf)))
            self._static_logged = True

        n = self.num_cells * num_movers
        if n:
            mover_xf = self._buffer("mover_xf", n, wp.transform)
            mover_col = self._buffer("mover_col", n, wp.vec3)
            zone_xf = self._buffer("zone_xf", n, wp.transform)
            zone_sc = self._buffer("zone_sc", n, wp.vec3)
            zone_col = self._buffer("zone_col", n, wp.vec3)
            goal_xf = self._buffer("goal_xf", n, wp.transform)
            ms = self.mover.size
            wp.launch(mover_instances, dim=(self.num_cells, num_movers), device=self.device, inputs=[
                self._cell_worlds, self._offsets, self._palette, wp.vec3(*(np.asarray(colors.COLLISION) / 255.0)),
                wp.vec3(0.5 * ms[0], 0.5 * ms[1], 0.5 * ms[2]), float(self.mover.hover_z),
                1 if self.mover.collision_shape == "box" else 0, float(self.mover.margin),
                wp.from_torch(radii_t), wp.from_torch(half_t),
                wp.from_torch(pos_t), wp.from_torch(rot_t), wp.from_torch(flags_t), wp.from_torch(goals_t),
            ], outputs=[mover_xf, mover_col, zone_xf, zone_sc, zone_col, goal_xf])
            half = wp.vec3(0.5 * ms[0], 0.5 * ms[1], 0.5 * ms[2])
            v.log_instances("/magwarp/movers", _BOX, mover_xf, self._const("mover_scale", n, half, wp.vec3), mover_col,
                            self._materials(n))
            zone_mesh = _BOX if self.mover.collision_shape == "box" else _CYLINDER
            v.log_instances("/magwarp/safety_zones", zone_mesh, zone_xf, zone_sc, zone_col, self._materials(n),
                            opacities=self._const("zone_opacity", n, 0.35, wp.float32))
            if goals is not None:
                r = 0.015
                v.log_instances("/magwarp/goals", _SPHERE, goal_xf, self._const("goal_scale", n, (r, r, r), wp.vec3),
                                mover_col, self._materials(n))

        self._log_parts("objects", object_poses, colors.OBJECT, 1.0, num_worlds)
        self._log_parts("object_goals", object_goals, colors.OBJECT_GOAL, 0.4, num_worlds)
        if obstacles is not None:
            obst_t = per_world(obstacles, trailing=(5,), allow_trailing=(4, 5), name="obstacles", device=td)
            if obst_t.shape[-1] == 4:
                obst_t = torch.cat([obst_t, torch.zeros_like(obst_t[..., :1])], dim=-1)
            k = obst_t.shape[1]
            if k:
                xf = self._buffer("obst_xf", self.num_cells * k, wp.transform)
                sc = self._buffer("obst_sc", self.num_cells * k, wp.vec3)
                wp.launch(obstacle_instances, dim=(self.num_cells, k), device=self.device,
                          inputs=[self._cell_worlds, self._offsets, OBSTACLE_HALF_HEIGHT, wp.from_torch(obst_t)],
                          outputs=[xf, sc])
                col = self._const("obst_col", len(xf), np.asarray(colors.OBSTACLE, np.float32) / 255.0, wp.vec3)
                v.log_instances("/magwarp/obstacles", _BOX, xf, sc, col, self._materials(len(xf)))
        v.end_frame()
        self.frame += 1

    def _log_parts(self, name: str, poses, rgb, opacity: float, num_worlds: int) -> None:
        if poses is None:
            return
        import torch

        from magwarp.render.arrays import as_tensor, per_world

        num_objects, num_parts = self._parts_np.shape[:2]
        if num_objects == 0:
            raise ValueError(f"{name} given, but the viewer was built without object_shapes")
        td = wp.device_to_torch(self.device)
        t = as_tensor(poses, device=td, dtype=torch.float32, name=name)
        if t.ndim == 2 and num_objects == 1 and t.shape[0] != 1:
            t = t.unsqueeze(1)
        t = per_world(t, trailing=(3,), name=name, device=td, num_items=num_objects)
        n = self.num_cells * num_objects * num_parts
        box_xf, box_sc = self._buffer(f"{name}_bxf", n, wp.transform), self._buffer(f"{name}_bsc", n, wp.vec3)
        disc_xf, disc_sc = self._buffer(f"{name}_dxf", n, wp.transform), self._buffer(f"{name}_dsc", n, wp.vec3)
        wp.launch(part_instances, dim=(self.num_cells, num_objects, num_parts), device=self.device,
                  inputs=[self._cell_worlds, self._offsets, self._parts, OBJECT_HALF_HEIGHT, wp.from_torch(t)],
                  outputs=[box_xf, box_sc, disc_xf, disc_sc])
        col = self._const(f"{name}_col", n, np.asarray(rgb, np.float32) / 255.0, wp.vec3)
        op = self._const(f"{name}_op", n, opacity, wp.float32) if opacity < 1.0 else None
        self.viewer.log_instances(f"/magwarp/{name}/boxes", _BOX, box_xf, box_sc, col, self._materials(n), opacities=op)
        self.viewer.log_instances(f"/magwarp/{name}/discs", _CYLINDER, disc_xf, disc_sc, col, self._materials(n),
                                  opacities=op)

    def is_running(self) -> bool:
        return bool(self.viewer.is_running())

    def close(self) -> None:
        self.viewer.close()


def _is_file_backend(viewer) -> bool:
    return type(viewer).__name__ in ("ViewerUSD",)
