"""MJCF (MuJoCo XML) generation for magnetic levitation scenes: tiles, movers, pushable objects, obstacles, user hooks.

The generator is a single pass of string formatting (linear in tiles + movers + objects), so it is cheap enough to
run at every reset that changes geometry. Naming (stable, used by :mod:`magwarp.physics`):

- tiles ``tile_{i}_{j}`` (geoms in the world body; tile tops at z = 0); unless ``tile_collision="tiles"`` they are
  visual only and ``tile_support_{r}`` geoms (a plane, or boxes covering the tiles; tile contact bits) carry objects,
- movers ``mover_{k}`` (body), ``mover_joint_{k}`` (free joint), ``mover_geom_{k}``; movers come first in the body
  tree, so their free joints occupy ``qpos[7k:7k+7]`` / ``qvel[6k:6k+6]`` unless a mover hook adds joints,
- objects ``object_{k}`` (body), ``object_joint_{k}``, ``object_{k}_geom_{g}``; optional visual-only goal markers
  ``object_goal_{k}`` are mocap bodies, so goals move per world without a rebuild,
- obstacles ``obstacle_geom_{k}`` (static geoms in the world body).

Contact filtering uses contype/conaffinity bits instead of MagBotSim's O(N^2) ``<exclude>`` list. MuJoCo collides
geoms a, b iff ``(contype_a & conaffinity_b) | (contype_b & conaffinity_a)``:

=============  =======  ===========  ==================================================
geom           contype  conaffinity  collides with
=============  =======  ===========  ==================================================
tile           2        1            bit-0 geoms (objects, obstacles, user geoms)
mover          4        1            bit-0 geoms
everything     1        1            (MuJoCo's default) tiles, movers and each other
=============  =======  ===========  ==================================================

So mover-mover and mover-tile pairs never collide (movers hover; their collisions are detected geometrically), while
any user geom left at MuJoCo's defaults interacts with tiles, movers and objects without extra configuration.

Gravity compensation: movers carry ``gravcomp="1"``. MuJoCo (C and mujoco-warp alike) then adds the exact
``-m g`` of the mover's subtree as a passive force, so the hover needs no controller state, holds in any MuJoCo
viewer or tool that loads the XML, and bodies attached to a mover by a hook get compensated by their own
``gravcomp`` choice. The impedance controller in :mod:`magwarp.physics` only adds the z/attitude hold.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields

import numpy as np

from magwarp.layout import Layout, LayoutError, MoverSpec

__all__ = [
    "OBJECT_SHAPES",
    "ObjectSpec",
    "ObstacleSpec",
    "XmlHooks",
    "generate_mjcf",
    "tile_rectangles",
    "TILE_CONTYPE",
    "TILE_CONAFFINITY",
    "MOVER_CONTYPE",
    "MOVER_CONAFFINITY",
]

TILE_CONTYPE, TILE_CONAFFINITY = 2, 1
MOVER_CONTYPE, MOVER_CONAFFINITY = 4, 1

# Canonical names plus short aliases ("T", "L", "X", "plus").
_SHAPE_ALIASES = {
    "box": "box",
    "square_box": "square_box",
    "cylinder": "cylinder",
    "t_shape": "t_shape",
    "t": "t_shape",
    "l_shape": "l_shape",
    "l": "l_shape",
    "plus_shape": "plus_shape",
    "x_shape": "plus_shape",
    "x": "plus_shape",
    "plus": "plus_shape",
}
OBJECT_SHAPES = ("box", "square_box", "cylinder", "t_shape", "l_shape", "plus_shape")


def _f(x) -> str:
    """Short exact-enough float text (10 significant digits; numpy scalars print as plain numbers)."""
    return format(float(x), ".10g")


def _positive(owner: str, name: str, value, maximum: float = np.inf) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise LayoutError(f"{owner}.{name} must be a positive finite number, got {value!r}")
    if value > maximum:
        raise LayoutError(f"{owner}.{name} must be at most {maximum:g}, got {value!r}")
    return value


#: Bounds of a pushable object: half-sizes (m) and mass (kg). A planar motor's objects are centimetres to a metre;
#: beyond these the float32 physics (inertia ~ m d^2) overflows (a fuzz draw: object_depth=1.18e21 gave NaN).
OBJECT_SIZE_MAX, OBJECT_MASS_MAX = 10.0, 1e4


@dataclass(frozen=True)
class ObjectSpec:
    """A pushable rigid object made of box geoms (or one cylinder). All sizes are half-sizes in metres.

    Shapes (MagBotSim's definitions): ``box`` (``width`` x ``height``), ``square_box`` (``width`` x ``width``),
    ``cylinder`` (``radius``), ``t_shape``, ``l_shape`` and ``plus_shape`` (aliases ``T``, ``L``, ``X``): a stem of
    half-size (``segment_width``, ``height``) plus one or two bars of half-thickness ``segment_width`` that span the
    full half-width ``width``. ``depth`` is the half-height (z). Mass is split over the parts by volume.
    """

    shape: str = "square_box"
    width: float = 0.06
    height: float = 0.06
    depth: float = 0.02
    segment_width: float = 0.02
    radius: float = 0.05
    mass: float = 0.3
    friction: tuple[float, float, float] = (1.0, 0.005, 0.0001)

    def __post_init__(self):
        key = str(self.shape).lower()
        if key not in _SHAPE_ALIASES:
            raise LayoutError(f"ObjectSpec.shape {self.shape!r} is unknown; choose one of {OBJECT_SHAPES} (or T, L, X)")
        object.__setattr__(self, "shape", _SHAPE_ALIASES[key])
        for name in ("width", "height", "depth", "segment_width", "radius", "mass"):
            bound = OBJECT_MASS_MAX if name == "mass" else OBJECT_SIZE_MAX
            object.__setattr__(self, name, _positive("ObjectSpec", name, getattr(self, name), bound))
        fr = tuple(float(v) for v in self.friction)
        if len(fr) != 3 or not all(np.isfinite(v) and v >= 0 for v in fr):
            raise LayoutError(f"ObjectSpec.friction must be three non-negative numbers, got {self.friction!r}")
        object.__setattr__(self, "friction", fr)
        if self.shape in ("t_shape", "l_shape", "plus_shape") and not self.segment_width < self.width:
            raise LayoutError(
                f"ObjectSpec.segment_width ({self.segment_width}) must be smaller than width ({self.width}) for {self.shape}"
            )
        if self.shape in ("t_shape", "l_shape") and not self.segment_width < self.height:
            raise LayoutError(
                f"ObjectSpec.segment_width ({self.segment_width}) must be smaller than height ({self.height}) for {self.shape}"
            )

    def rects(self) -> np.ndarray:
        """The box parts in the body frame, shape ``(k, 4)`` rows ``(cx, cy, hx, hy)``; empty for a cylinder.

        Parts of T/L/X shapes are disjoint (they only share edges), so the object's area is the sum of part areas.
        """
        w, h, s = self.width, self.height, self.segment_width
        bar_half = 0.5 * (w - s)  # half-length of a side bar: stem half-width s + bar length 2*bar_half == w
        bar_pos = bar_half + s
        if self.shape == "square_box":
            return np.array([[0.0, 0.0, w, w]])
        if self.shape == "box":
            return np.array([[0.0, 0.0, w, h]])
        if self.shape == "cylinder":
            return np.zeros((0, 4))
        stem = [0.0, 0.0, s, h]
        if self.shape == "t_shape":
            return np.array([stem, [-bar_pos, h - s, bar_half, s], [bar_pos, h - s, bar_half, s]])
        if self.shape == "l_shape":
            return np.array([stem, [bar_pos, -(h - s), bar_half, s]])
        return np.array([stem, [-bar_pos, 0.0, bar_half, s], [bar_pos, 0.0, bar_half, s]])  # plus_shape

    @property
    def area(self) -> float:
        """Footprint area (m^2)."""
        if self.shape == "cylinder":
            return float(np.pi * self.radius**2)
        r = self.rects()
        return float(np.sum(4.0 * r[:, 2] * r[:, 3]))

    @property
    def xy_extent(self) -> float:
        """Radius of a circle around the footprint (used for spawn spacing)."""
        if self.shape == "cylinder":
            return self.radius
        r = self.rects()
        return float(np.max(np.hypot(np.abs(r[:, 0]) + r[:, 2], np.abs(r[:, 1]) + r[:, 3])))

    def geoms_xml(self, prefix: str, contype: int | None = None, extra: str = "") -> str:
        """``<geom>`` lines of this object; ``contype``/``conaffinity`` are set to it if given (goal markers use 0)."""
        col = "" if contype is None else f' contype="{contype}" conaffinity="{contype}"'
        d = _f(self.depth)
        if self.shape == "cylinder":
            return f'<geom name="{prefix}_0" type="cylinder" size="{_f(self.radius)} {d}" mass="{_f(self.mass)}"{col}{extra}/>'
        rects = self.rects()
        areas = 4.0 * rects[:, 2] * rects[:, 3]
        masses = self.mass * areas / areas.sum()
        return "".join(
            f'<geom name="{prefix}_{g}" type="box" pos="{_f(cx)} {_f(cy)} 0" size="{_f(hx)} {_f(hy)} {d}" '
            f'mass="{_f(m)}"{col}{extra}/>'
            for g, ((cx, cy, hx, hy), m) in enumerate(zip(rects, masses))
        )


@dataclass(frozen=True)
class ObstacleSpec:
    """A static box obstacle: centre ``(x, y)`` on the tiles, half-sizes ``(hx, hy, hz)``, yaw (rad)."""

    xy: tuple[float, float]
    half_size: tuple[float, float, float] = (0.03, 0.1, 0.03)
    yaw: float = 0.0

    def __post_init__(self):
        xy = tuple(float(v) for v in self.xy)
        if len(xy) != 2 or not all(np.isfinite(xy)):
            raise LayoutError(f"ObstacleSpec.xy must be two finite numbers, got {self.xy!r}")
        half = tuple(float(v) for v in self.half_size)
        if len(half) != 3 or not all(np.isfinite(v) and v > 0 for v in half):
            raise LayoutError(f"ObstacleSpec.half_size must be three positive numbers, got {self.half_size!r}")
        if not np.isfinite(self.yaw):
            raise LayoutError(f"ObstacleSpec.yaw must be finite, got {self.yaw!r}")
        object.__setattr__(self, "xy", xy)
        object.__setattr__(self, "half_size", half)
        object.__setattr__(self, "yaw", float(self.yaw))


@dataclass(frozen=True)
class XmlHooks:
    """User XML spliced into the generated model (robots, sensors, extra objects, ...).

    ``assets``, ``defaults``, ``worldbody``, ``contact``, ``actuator``, ``sensor``, ``equality`` and ``tendon`` are
    inserted inside the section of the same name; ``extra`` goes after all sections (``<include>``, keyframes, ...).
    ``compiler``/``option``/``visual`` replace the whole default element when given. ``mover_bodies`` is a sequence
    (one entry per mover, ``None`` for none) of XML placed inside each mover body, e.g. a gripper. User geoms keep
    MuJoCo's default contype/conaffinity (1/1) and therefore collide with tiles, movers and objects.
    """

    assets: str = ""
    defaults: str = ""
    worldbody: str = ""
    contact: str = ""
    actuator: str = ""
    sensor: str = ""
    equality: str = ""
    tendon: str = ""
    extra: str = ""
    compiler: str | None = None
    option: str | None = None
    visual: str | None = None
    mover_bodies: Sequence[str | None] | None = None

    @classmethod
    def coerce(cls, hooks: "XmlHooks | Mapping[str, object] | None") -> "XmlHooks":
        if hooks is None:
            return cls()
        if isinstance(hooks, XmlHooks):
            return hooks
        if not isinstance(hooks, Mapping):
            raise LayoutError(f"xml hooks must be an XmlHooks or a dict, got {type(hooks).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(hooks) - known)
        if unknown:
            raise LayoutError(f"unknown xml hook key(s) {unknown}; valid keys are {sorted(known)}")
        return cls(**hooks)


@dataclass(frozen=True)
class _Scene:
    """Resolved numeric inputs (validated) for one XML generation."""

    mover_xy: np.ndarray
    object_xy: np.ndarray
    object_yaw: np.ndarray
    goal_xy: np.ndarray
    goal_yaw: np.ndarray
    extra: dict = field(default_factory=dict)


def _as_xy(name: str, value, n: int, default: np.ndarray) -> np.ndarray:
    if value is None:
        return default
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (n, 2):
        raise LayoutError(f"{name} must have shape ({n}, 2), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise LayoutError(f"{name} must be finite, got {arr!r}")
    return arr


def _as_vec(name: str, value, n: int) -> np.ndarray:
    if value is None:
        return np.zeros(n)
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise LayoutError(f"{name} must be {n} finite numbers, got {value!r}")
    return arr


def tile_rectangles(tiles: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Cover the present tiles with few axis-aligned rectangles ``(i0, j0, ni, nj)`` (tile units), no overlaps.

    Greedy: maximal runs along x per row j, then runs with the same x-extent in consecutive rows are merged.
    Linear in the number of grid cells.
    """
    nx, ny = tiles.shape
    open_runs: dict[tuple[int, int], list[int]] = {}  # (i0, ni) -> [j0, nj] of the rectangle still growing
    done: list[tuple[int, int, int, int]] = []
    for j in range(ny):
        runs = []
        i = 0
        while i < nx:
            if tiles[i, j]:
                i0 = i
                while i < nx and tiles[i, j]:
                    i += 1
                runs.append((i0, i - i0))
            else:
                i += 1
        grown = {}
        for run in runs:
            if run in open_runs:
                j0, nj = open_runs.pop(run)
                grown[run] = [j0, nj + 1]
            else:
                grown[run] = [j, 1]
        done.extend((i0, j0, ni, nj) for (i0, ni), (j0, nj) in open_runs.items())
        open_runs = grown
    done.extend((i0, j0, ni, nj) for (i0, ni), (j0, nj) in open_runs.items())
    return sorted(done)


def _quat_z(yaw: float) -> str:
    return f"{_f(np.cos(0.5 * yaw))} 0 0 {_f(np.sin(0.5 * yaw))}"


_ASSETS = (
    '<texture name="grid" type="2d" builtin="checker" rgb1=".82 .82 .82" rgb2=".74 .74 .74" width="64" height="64"/>'
    '<material name="tile" texture="grid" texrepeat="1 1" reflectance="0.01"/>'
    '<material name="mover" rgba="0.25 0.25 0.28 1"/>'
    '<material name="object" rgba="0.94 0.19 0.19 1"/>'
    '<material name="goal" rgba="1 0 0 0.2"/>'
    '<material name="obstacle" rgba="0.4 0.4 0.45 1"/>'
)


def generate_mjcf(
    layout: Layout,
    num_movers: int,
    mover: MoverSpec | None = None,
    *,
    mover_xy=None,
    objects: Sequence[ObjectSpec] = (),
    object_xy=None,
    object_yaw=None,
    goal_markers: bool = False,
    goal_xy=None,
    goal_yaw=None,
    obstacles: Sequence[ObstacleSpec] = (),
    hooks: XmlHooks | Mapping[str, object] | None = None,
    timestep: float = 0.001,
    gravity: float = -9.81,
    mover_friction: tuple[float, float, float] = (1.0, 0.005, 0.0001),
    tile_collision: str = "auto",
    solver: str = "Newton",
    iterations: int = 100,
    ls_iterations: int = 50,
    model_name: str = "magwarp",
) -> str:
    """Return an MJCF string for ``layout`` with ``num_movers`` movers, pushable ``objects`` and static ``obstacles``.

    ``mover_xy`` ``(num_movers, 2)`` defaults to tile centres (one mover per tile); ``object_xy`` ``(len(objects), 2)``
    defaults to the layout's centre; yaws are in radians. These are only the model's default (``qpos0``) pose: the
    physics backend overrides start poses per world without regenerating the XML. ``goal_markers`` adds a
    transparent, non-colliding mocap copy of each object (its pose lives in ``mocap_pos``/``mocap_quat`` per world).
    Cost is linear in tiles + movers + objects + obstacles.

    ``tile_collision`` chooses the support surface that objects touch. ``"auto"`` (default) is ``"plane"`` for a
    layout without holes and ``"merged"`` otherwise. ``"merged"`` draws the tiles but
    collides against a few boxes covering the same area (:func:`tile_rectangles`; one box for a full grid), so an
    object sliding across a seam between two flush tiles meets no spurious edge contacts (and needs half the contacts
    while it straddles one); ``"tiles"`` collides with every tile box (MagBotSim's model); ``"plane"`` uses one
    infinite plane at z = 0 (fastest and numerically the most robust: mujoco-warp's float32 box-box test can miss
    a resting contact shallower than ~1e-4 m that MuJoCo C sees, while plane-box contacts agree to ~1e-8; objects
    are not dropped at the layout's outer edge).

    ``solver`` is MuJoCo's constraint solver (``"Newton"``, MuJoCo's default and MagBotSim's, or ``"CG"``):
    the contact problem and its converged solution are the same, only the optimiser and its cost per step differ.
    ``iterations`` and ``ls_iterations`` cap its iterations and line-search steps per step (MuJoCo's defaults: 100
    and 50); fewer trade accuracy in the hardest contact configurations for speed.
    """
    if not isinstance(layout, Layout):
        raise LayoutError(f"layout must be a magwarp.layout.Layout, got {type(layout).__name__}")
    mover = mover or MoverSpec()
    if not isinstance(mover, MoverSpec):
        raise LayoutError(f"mover must be a MoverSpec, got {type(mover).__name__}")
    if int(num_movers) != num_movers or num_movers < 0:
        raise LayoutError(f"num_movers must be a non-negative integer, got {num_movers!r}")
    num_movers = int(num_movers)
    objects = tuple(objects)
    obstacles = tuple(obstacles)
    for k, o in enumerate(objects):
        if not isinstance(o, ObjectSpec):
            raise LayoutError(f"objects[{k}] must be an ObjectSpec, got {type(o).__name__}")
    for k, o in enumerate(obstacles):
        if not isinstance(o, ObstacleSpec):
            raise LayoutError(f"obstacles[{k}] must be an ObstacleSpec, got {type(o).__name__}")
    timestep = _positive("generate_mjcf", "timestep", timestep)
    for name, value in (("iterations", iterations), ("ls_iterations", ls_iterations)):
        if int(value) != value or value < 1:
            raise LayoutError(f"{name} must be a positive integer, got {value!r}")
    if solver not in ("Newton", "CG"):
        raise LayoutError(f"solver must be 'Newton' or 'CG' (the solvers mujoco-warp has), got {solver!r}")
    if tile_collision not in ("auto", "merged", "tiles", "plane"):
        raise LayoutError(f"tile_collision must be 'auto', 'merged', 'tiles' or 'plane', got {tile_collision!r}")
    if tile_collision == "auto":
        tile_collision = "plane" if layout.tiles.all() else "merged"
    hooks = XmlHooks.coerce(hooks)
    if hooks.mover_bodies is not None and len(hooks.mover_bodies) != num_movers:
        raise LayoutError(f"hooks.mover_bodies must have one entry per mover ({num_movers}), got {len(hooks.mover_bodies)}")
    fr = tuple(float(v) for v in mover_friction)
    if len(fr) != 3 or not all(np.isfinite(v) and v >= 0 for v in fr):
        raise LayoutError(f"mover_friction must be three non-negative numbers, got {mover_friction!r}")

    if mover_xy is None:
        m_xy = layout.default_starts(num_movers) if num_movers else np.zeros((0, 2))
    else:
        m_xy = _as_xy("mover_xy", mover_xy, num_movers, None)
    centre = 0.5 * np.asarray(layout.extent)
    o_xy = _as_xy("object_xy", object_xy, len(objects), np.tile(centre, (len(objects), 1)))
    o_yaw = _as_vec("object_yaw", object_yaw, len(objects))
    g_xy = _as_xy("goal_xy", goal_xy, len(objects), o_xy.copy())
    g_yaw = _as_vec("goal_yaw", goal_yaw, len(objects))

    tile = layout.tile
    th = 0.5 * tile.height
    out: list[str] = [
        f'<mujoco model="{model_name}">',
        hooks.compiler if hooks.compiler is not None else '<compiler angle="radian" autolimits="true"/>',
        hooks.option
        if hooks.option is not None
        else f'<option timestep="{_f(timestep)}" gravity="0 0 {_f(gravity)}" cone="elliptic" solver="{solver}" '
        f'iterations="{int(iterations)}" ls_iterations="{int(ls_iterations)}"/>',
        hooks.visual if hooks.visual is not None else '<visual><global offwidth="1280" offheight="960"/></visual>',
        "<asset>",
        _ASSETS,
        hooks.assets,
        "</asset>",
        "<default>",
        f'<default class="tile"><geom type="box" size="{_f(tile.half)} {_f(tile.half)} {_f(th)}" material="tile" '
        f'contype="{TILE_CONTYPE}" conaffinity="{TILE_CONAFFINITY}" group="0"/></default>',
        f'<default class="mover"><geom type="box" material="mover" contype="{MOVER_CONTYPE}" '
        f'conaffinity="{MOVER_CONAFFINITY}" friction="{_f(fr[0])} {_f(fr[1])} {_f(fr[2])}" group="2"/></default>',
        '<default class="goal"><geom contype="0" conaffinity="0" material="goal" group="1"/></default>',
        hooks.defaults,
        "</default>",
        "<worldbody>",
        '<light directional="true" pos="0 0 3" dir="0 0 -1" diffuse="0.8 0.8 0.8"/>',
    ]

    # Tiles: static geoms in the world body, top surface at z = 0. Visual-only plane far below as a floor.
    ii, jj = np.nonzero(layout.tiles)
    cx = (2 * ii + 1) * tile.half
    cy = (2 * jj + 1) * tile.half
    z_tile = _f(-th)
    tile_col = "" if tile_collision == "tiles" else ' contype="0" conaffinity="0"'
    out.extend(
        f'<geom name="tile_{i}_{j}" class="tile" pos="{_f(x)} {_f(y)} {z_tile}"{tile_col}/>'
        for i, j, x, y in zip(ii, jj, cx, cy)
    )
    if tile_collision == "merged":
        for r, (i0, j0, ni, nj) in enumerate(tile_rectangles(layout.tiles)):
            out.append(
                f'<geom name="tile_support_{r}" class="tile" pos="{_f((i0 + 0.5 * ni) * tile.size)} '
                f'{_f((j0 + 0.5 * nj) * tile.size)} {z_tile}" size="{_f(0.5 * ni * tile.size)} {_f(0.5 * nj * tile.size)} '
                f'{_f(th)}" group="3" rgba="0 0 0 0"/>'
            )
    elif tile_collision == "plane":
        out.append(
            f'<geom name="tile_support_0" type="plane" size="0 0 1" contype="{TILE_CONTYPE}" '
            f'conaffinity="{TILE_CONAFFINITY}" group="3" rgba="0 0 0 0"/>'
        )

    # Movers first, so their free joints own the leading qpos/qvel slots.
    hx, hy, hz = (0.5 * s for s in mover.size)
    z_mover = _f(mover.hover_z)
    size_txt = f"{_f(hx)} {_f(hy)} {_f(hz)}"
    mass_txt = _f(mover.mass)
    bodies = hooks.mover_bodies or (None,) * num_movers
    for k in range(num_movers):
        out.append(
            f'<body name="mover_{k}" pos="{_f(m_xy[k, 0])} {_f(m_xy[k, 1])} {z_mover}" gravcomp="1" childclass="mover">'
            f'<freejoint name="mover_joint_{k}"/>'
            f'<geom name="mover_geom_{k}" size="{size_txt}" mass="{mass_txt}"/>'
            f"{bodies[k] or ''}</body>"
        )

    for k, obj in enumerate(objects):
        ofr = obj.friction
        fr_txt = f' friction="{_f(ofr[0])} {_f(ofr[1])} {_f(ofr[2])}" material="object" priority="1"'
        out.append(
            f'<body name="object_{k}" pos="{_f(o_xy[k, 0])} {_f(o_xy[k, 1])} {_f(obj.depth)}" quat="{_quat_z(o_yaw[k])}">'
            f'<freejoint name="object_joint_{k}"/>{obj.geoms_xml(f"object_{k}_geom", extra=fr_txt)}</body>'
        )
    if goal_markers:
        for k, obj in enumerate(objects):
            out.append(
                f'<body name="object_goal_{k}" mocap="true" pos="{_f(g_xy[k, 0])} {_f(g_xy[k, 1])} {_f(obj.depth)}" '
                f'quat="{_quat_z(g_yaw[k])}" childclass="goal">{obj.geoms_xml(f"object_goal_{k}_geom", contype=0)}</body>'
            )

    for k, obs in enumerate(obstacles):
        ox, oy = obs.xy
        sx, sy, sz = obs.half_size
        out.append(
            f'<geom name="obstacle_geom_{k}" type="box" pos="{_f(ox)} {_f(oy)} {_f(sz)}" quat="{_quat_z(obs.yaw)}" '
            f'size="{_f(sx)} {_f(sy)} {_f(sz)}" material="obstacle"/>'
        )

    out.append(hooks.worldbody)
    out.append("</worldbody>")
    for section in ("contact", "actuator", "sensor", "equality", "tendon"):
        text = getattr(hooks, section)
        if text:
            out.append(f"<{section}>{text}</{section}>")
    out.append(hooks.extra)
    out.append("</mujoco>")
    return "\n".join(s for s in out if s)
