"""3D images of MuJoCo scenes (push envs) through MuJoCo's offscreen OpenGL renderer, one world at a time.

    from magwarp.render.mujoco3d import render_world, render_worlds
    img = render_world(env, world=0, width=640, height=480)      # numpy uint8 [480, 640, 3]
    mosaic = render_worlds(env, 4)                                # worlds 0..3 side by side

The world's ``qpos`` is copied from the mujoco-warp backend (device) into a host ``MjData``, its kinematics are
computed and MuJoCo draws it: tiles, movers (red when the world collided), the object, its goal as a translucent
green copy, and obstacles, in the top-down renderer's colours. Push envs expose it as
``render_mode="rgb_array_3d"``.

Headless OpenGL: EGL (GPU, or Mesa's software EGL) or OSMesa (CPU, Debian ``libosmesa6``). The backend is chosen
from ``MUJOCO_GL`` (``egl`` or ``osmesa``) when set, else EGL when ``libEGL`` is found, else OSMesa. PyOpenGL binds
one platform per process, so set ``MUJOCO_GL`` before anything imports OpenGL to choose. Where none loads,
:class:`GLUnavailableError` says so in one line.
"""

from __future__ import annotations

import ctypes.util
import math
import os
from collections.abc import Sequence

import numpy as np

__all__ = ["GLUnavailableError", "gl_backend", "MujocoSceneRenderer", "render_world", "render_worlds"]

GOAL_RGBA = (0.24, 0.67, 0.35, 0.45)  # colors.OBJECT_GOAL, translucent
COLLISION_RGBA = (0.84, 0.15, 0.16, 1.0)  # colors.COLLISION
OBJECT_RGBA = (0.77, 0.56, 0.29, 1.0)  # colors.OBJECT (wood-like tan)
_BACKEND: str | None = None
_BACKEND_ERROR: str | None = None


class GLUnavailableError(RuntimeError):
    """No headless OpenGL backend (EGL / OSMesa) could be loaded on this machine."""


def gl_backend() -> str:
    """The headless OpenGL backend used here: ``"egl"`` or ``"osmesa"`` (raises :class:`GLUnavailableError`)."""
    global _BACKEND, _BACKEND_ERROR
    if _BACKEND is not None:
        return _BACKEND
    if _BACKEND_ERROR is not None:
        raise GLUnavailableError(_BACKEND_ERROR)
    hint = ("install EGL (libegl1, with a GPU driver or Mesa) or OSMesa (apt-get install libosmesa6) and set "
            "MUJOCO_GL=egl or MUJOCO_GL=osmesa")
    want = os.environ.get("MUJOCO_GL", "").lower().strip()
    platform = os.environ.get("PYOPENGL_PLATFORM", "").lower().strip()
    if want in ("egl", "osmesa"):
        candidates = [want]
    elif want not in ("", "glfw", "glx", "on", "enable", "enabled", "true", "1"):
        _BACKEND_ERROR = f"3D rendering is off (MUJOCO_GL={want!r}); {hint}"
        raise GLUnavailableError(_BACKEND_ERROR)
    elif platform in ("egl", "osmesa"):
        candidates = [platform]
    else:
        candidates = [name for name, lib in (("egl", "EGL"), ("osmesa", "OSMesa")) if ctypes.util.find_library(lib)]
    if not candidates:
        _BACKEND_ERROR = f"no headless OpenGL library (libEGL, libOSMesa) found for MuJoCo's 3D renderer; {hint}"
        raise GLUnavailableError(_BACKEND_ERROR)
    name = candidates[0]  # PyOpenGL binds one platform per process: no second try after a failed import
    try:
        ctx = _context_class(name)(16, 16)
        ctx.free()
    except Exception as e:  # noqa: BLE001 - any failure to load or create a context means "not available"
        _BACKEND_ERROR = f"MuJoCo's {name.upper()} OpenGL backend did not load ({type(e).__name__}: {e}); {hint}"
        raise GLUnavailableError(_BACKEND_ERROR) from e
    _BACKEND = name
    return name


def _context_class(name: str):
    if name == "egl":
        from mujoco.egl import GLContext
    else:
        from mujoco.osmesa import GLContext
    return GLContext


class MujocoSceneRenderer:
    """Offscreen renderer of one MjModel at a fixed image size (GL context, MjrContext and MjvScene made once).

    ``draw(qpos, ...)`` sets a host ``MjData`` to ``qpos``, computes kinematics and returns an ``[H, W, 3]`` uint8
    image seen by a free camera looking down at ``lookat`` (default: the model's centre) from ``azimuth`` /
    ``elevation`` degrees. ``extra_boxes`` adds visual-only boxes/cylinders (goal ghosts) to the scene.
    """

    def __init__(self, model, width: int = 640, height: int = 480, *, lookat=None, distance: float | None = None,
                 azimuth: float = 90.0, elevation: float = -50.0):
        import mujoco

        if int(width) < 16 or int(height) < 16:
            raise ValueError(f"image size must be at least 16 x 16, got {width} x {height}")
        self.width, self.height = int(width), int(height)
        self._mj = mujoco
        backend = gl_backend()
        self.model = model
        # The offscreen buffer must hold the image: grow the model's limit (a visual setting; physics unchanged).
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), self.width)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), self.height)
        self.data = mujoco.MjData(model)
        self._gl = _context_class(backend)(self.width, self.height)
        self._gl.make_current()
        self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        self._scene = mujoco.MjvScene(model, maxgeom=10_000)
        self._opt = mujoco.MjvOption()
        self._pert = mujoco.MjvPerturb()
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        mujoco.mj_forward(model, self.data)
        extent = float(model.stat.extent)
        center = np.asarray(model.stat.center, dtype=np.float64)
        self.camera.lookat[:] = center if lookat is None else np.asarray(lookat, dtype=np.float64)
        self.camera.distance = 1.6 * extent if distance is None else float(distance)
        self.camera.azimuth = float(azimuth)
        self.camera.elevation = float(elevation)
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)

    def draw(self, qpos, mocap_pos=None, mocap_quat=None, *, extra_boxes=(),
             geom_rgba: dict | None = None) -> np.ndarray:
        """Render the model at ``qpos`` (host array ``[nq]``). ``extra_boxes``: ``(pos, yaw, size, rgba, kind)``
        with ``kind`` ``"box"`` (``size`` = half sizes) or ``"cylinder"`` (radius, half height); ``geom_rgba``:
        geom id -> rgba overrides for this frame."""
        mj, m, d = self._mj, self.model, self.data
        d.qpos[:] = np.asarray(qpos, dtype=np.float64).reshape(-1)
        if mocap_pos is not None:
            d.mocap_pos[:] = mocap_pos
        if mocap_quat is not None:
            d.mocap_quat[:] = mocap_quat
        mj.mj_kinematics(m, d)
        mj.mj_camlight(m, d)
        self._gl.make_current()
        scn = self._scene
        mj.mjv_updateScene(m, d, self._opt, self._pert, self.camera, mj.mjtCatBit.mjCAT_ALL, scn)
        if geom_rgba:
            for i in range(scn.ngeom):
                g = scn.geoms[i]
                if g.objtype == mj.mjtObj.mjOBJ_GEOM and g.objid in geom_rgba:
                    g.rgba[:] = geom_rgba[g.objid]
        for pos, yaw, size, rgba, kind in extra_boxes:
            if scn.ngeom >= scn.maxgeom:
                break
            c, s = math.cos(yaw), math.sin(yaw)
            mat = np.array([c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0])
            gtype = mj.mjtGeom.mjGEOM_BOX if kind == "box" else mj.mjtGeom.mjGEOM_CYLINDER
            mj.mjv_initGeom(scn.geoms[scn.ngeom], gtype, np.asarray(size, np.float64), np.asarray(pos, np.float64),
                            mat, np.asarray(rgba, np.float32))
            scn.ngeom += 1
        mj.mjr_render(self._rect, scn, self._con)
        mj.mjr_readPixels(self._rgb, None, self._rect, self._con)
        return np.flipud(self._rgb).copy()

    def close(self) -> None:
        if self._gl is not None:
            self._con.free()
            self._gl.free()
            self._gl = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass


def _env_renderer(env, width: int, height: int) -> MujocoSceneRenderer:
    cache = env.__dict__.setdefault("_mujoco3d", {})
    key = (int(width), int(height))
    if key not in cache:
        import copy

        model = copy.copy(env.backend.mjm)  # own copy: the renderer grows its offscreen buffer size
        ext = np.asarray(env.layout.extent, dtype=np.float64)
        distance = 1.05 * float(max(ext[0], ext[1] * width / height)) + 0.1
        cache[key] = MujocoSceneRenderer(model, width, height, lookat=(0.5 * ext[0], 0.45 * ext[1], 0.0),
                                         distance=distance)
        names = [model.geom(i).name for i in range(model.ngeom)]
        cache[key].mover_geoms = [i for i, n in enumerate(names) if n.startswith("mover_geom_")]
        cache[key].object_geoms = [i for i, n in enumerate(names) if n.startswith("object_") and "_geom_" in n]
    return cache[key]


def _palette(k: int) -> tuple[float, float, float, float]:
    from magwarp.render.colors import MOVER_PALETTE

    return (*(v / 255.0 for v in MOVER_PALETTE[k % len(MOVER_PALETTE)]), 1.0)


def _goal_ghosts(env, world: int) -> list[tuple]:
    """The object goal of ``world`` as translucent visual boxes (or a cylinder)."""
    gx, gy = (float(v) for v in env.goal_xy[world].tolist())
    gyaw = float(env.goal_yaw[world]) if env.learn_pose else 0.0
    c, s = math.cos(gyaw), math.sin(gyaw)
    h = float(env.object.depth) * 1.01
    out = []
    for cx, cy, hx, hy in env.object_parts(world):
        pos = (gx + c * cx - s * cy, gy + s * cx + c * cy, h)
        if hy <= 0:
            out.append((pos, gyaw, (hx * 1.01, h, 0.0), GOAL_RGBA, "cylinder"))
        else:
            out.append((pos, gyaw, (hx * 1.01, hy * 1.01, h), GOAL_RGBA, "box"))
    return out


def render_world(env, world: int = 0, width: int = 640, height: int = 480) -> np.ndarray:
    """A 3D image (numpy uint8 ``[height, width, 3]``) of world ``world`` of a push or MagBot env on mujoco-warp."""
    env = getattr(env, "unwrapped", env)
    env = getattr(env, "vec", env)  # gymnasium.make's single-env view
    if not hasattr(env, "backend") or not hasattr(env.backend, "qpos_t"):
        raise TypeError(f"render_world needs an env on the mujoco-warp backend (a push env), got {type(env).__name__}")
    world = int(world)
    if not 0 <= world < env.num_envs:
        raise ValueError(f"world must be in [0, {env.num_envs}), got {world}")
    r = _env_renderer(env, width, height)
    b = env.backend
    # geometry that varies per world (e.g. PushWithObstacles' random walls) into the renderer's model copy
    for name, rows in b.batched_fields.items():
        field = getattr(r.model, name)
        field[:] = rows[world].detach().cpu().numpy().reshape(field.shape)
    qpos = b.qpos_t[world].detach().cpu().numpy()
    mocap = {}
    if b.mjm.nmocap:
        mocap = {"mocap_pos": b.mocap_pos[world].detach().cpu().numpy(),
                 "mocap_quat": b.mocap_quat[world].detach().cpu().numpy()}
    collided = bool(env.render_state()["flags"][world].any())
    # Movers in the top-down renderer's palette (red when the world collided), so both views read alike.
    rgba = {g: COLLISION_RGBA if collided else _palette(k) for k, g in enumerate(r.mover_geoms)}
    rgba.update({g: OBJECT_RGBA for g in r.object_geoms})  # red would read as "collided"
    # an env with goals of its own kind (the MagBot envs) draws them through goal_ghosts(world)
    ghosts = env.goal_ghosts(world) if hasattr(env, "goal_ghosts") else _goal_ghosts(env, world)
    return r.draw(qpos, **mocap, extra_boxes=ghosts, geom_rgba=rgba)


def render_worlds(env, worlds: int | Sequence[int] = 1, width: int | None = None, height: int | None = None,
                  border_px: int = 2) -> np.ndarray:
    """Worlds ``0..n-1`` (or the listed ones) rendered in 3D and tiled into a mosaic (dark separators)."""
    env = getattr(env, "unwrapped", env)
    env = getattr(env, "vec", env)
    ids = list(range(int(worlds))) if np.ndim(worlds) == 0 else [int(w) for w in worlds]
    if not ids:
        raise ValueError("worlds must name at least one world")
    n = len(ids)
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    if width is None:
        width = 640 if n == 1 else 480 if n <= 4 else 320
    if height is None:
        height = width * 3 // 4
    b = int(border_px)
    out = np.full((rows * (height + b) + b, cols * (width + b) + b, 3), 32, dtype=np.uint8)
    for k, w in enumerate(ids):
        r, c = divmod(k, cols)
        y, x = b + r * (height + b), b + c * (width + b)
        out[y:y + height, x:x + width] = render_world(env, w, width, height)
    return out
