"""Domain randomisation as declarative event terms, per world on the device, with no model rebuild.

An :class:`EventTerm` names a friendly ``field``, a distribution (:class:`Uniform`, :class:`LogUniform`,
:class:`Gaussian`), an operation (``"set"``: the draw is the value; ``"scale"``: nominal x draw; ``"add"``: nominal +
draw) and a mode (``"startup"``: once, when the env is built; ``"reset"``: at every reset, for the reset worlds only;
``"interval"``: every ``interval_steps`` env steps, for all worlds, before the step is simulated). Scale and add are
relative to each world's *nominal* value (the built model's), so they never compound across resets or intervals; when
several terms write one field, the one that fired last sets it. Draws use the env's torch generator (``seed`` and
``reset(seed=...)`` reproduce them) and every update is a handful of torch ops on the env's device: no host sync, no
recompilation (mujoco-warp reads model arrays at ``worldid % shape[0]``, so :meth:`MjwBackend.batch_model_fields`
makes them per world).

Fields of the mujoco-warp push envs (:class:`magwarp.envs.push.PushEnv` and its variants), one draw per target:

* ``object_mass`` (per object, kg) and ``mover_mass`` (per mover, kg): ``body_mass``; the body's principal inertia is
  scaled with the mass (uniform density), ``body_subtreemass`` of the body and its ancestors follows, and
  ``body_invweight0``/``dof_invweight0`` (the constraint solver's regularisation scales) are divided by the mass and
  inertia ratios (exact for a free body without children, which movers and objects are in these envs). The movers
  are gravity compensated (``gravcomp``) with their randomised mass, but the x/y controller
  (:mod:`magwarp.physics.control`) keeps applying ``nominal mass x commanded acceleration``: a heavier mover accelerates
  less, ``a = m_nominal a_cmd / m`` (a payload the controller does not know of). Not with a varying ``object_ranges``
  for ``object_mass`` (its variants set the object's mass rows at every reset: use its ``mass`` range).
* ``payload_mass`` (per mover, kg, op ``set`` or ``add``: the nominal payload is 0): a point mass at ``offset``
  (x, y, z in the mover's body frame, from its nominal centre of mass; default at it) added to the mover body: the
  mass, the centre of mass (``body_ipos``), and the inertia by the parallel-axis theorem about the new centre of mass
  (the diagonal terms in the body's principal frame; the products of inertia ``-mu r_i r_j`` of an offset off the
  principal axes are dropped), with the same caveats as ``mover_mass``. ``known=True``: the controller is
  configured for the payload (XPlanar's payload parametrisation): the law's mass becomes mover + payload per world
  (:meth:`~magwarp.physics.MjwBackend.batch_control`), so x/y follows the commands and the z damping is
  ``2 sqrt(K_z (m + p))``.
* ``object_friction`` (per object) and ``floor_friction`` (one per world): the sliding coefficient of the object's
  geoms, of the colliding tile geoms. The object's geoms have contact priority 1 (MuJoCo then takes their friction
  for every contact of the object), so with a ``floor_friction`` term the tiles get priority 2 (set once, for all
  worlds) and the object's friction, solref and solimp as their nominal values (their condim must match the
  object's): the nominal scene is unchanged, every contact with the floor takes the floor's friction from then on,
  and ``object_friction`` sets the object's contacts with the movers and obstacles.
* ``obstacle_xy`` (per obstacle, 2 values: x and y in m, op ``set`` or ``add``): the obstacle geom's position
  (``geom_pos`` and its world pose ``geom_xpos``, which mujoco-warp computes once for static geoms) and the env's
  ``obstacle_boxes`` (observations, checks and rendering read them). Not with obstacle modes that move the walls per
  episode (``PushWithObstaclesEnv`` ``random``, ``curriculum`` or a mix).

* ``mover_inertia`` (per mover, 3 principal moments, kg m^2): the mover body's ``body_inertia`` (instead of the
  nominal scaled with ``mover_mass``); the impedance law's damping keeps the built inertia.
* the control law's ``stiffness_lin`` (3; the law holds z only, so the z component acts, x/y are driven),
  ``stiffness_rot`` (3: roll, pitch, yaw), ``v_max``, ``a_max``, ``j_max`` (per mover): the law's gains and x/y
  limits per world (:meth:`~magwarp.physics.MjwBackend.batch_control`); the damping follows ``2 sqrt(K m)`` with the
  built mass and inertia. The largest stiffness must be stable at ``physics_dt`` for the lightest mover.
* ``collision_radius`` (circles), ``collision_half_size`` (2: boxes), ``collision_margin`` and ``wall_margin`` (one
  per world): the per-cycle geometric checks' sizes (:meth:`~magwarp.physics.mover_checks.MoverChecks.per_world`);
  starts are still sampled with the built sizes.
* object sizes: ``object_width``, ``object_height``, ``object_depth``, ``object_segment_width``, ``object_radius``
  (uniform, op ``set``, mode ``reset``): the env's ``object_ranges`` as terms (:func:`object_ranges_from_terms`),
  drawn per episode from ``object_variants`` pre-compiled variants, with the same draws for the same seed; with
  them, an ``object_mass`` term of that form is the ranges' ``"mass"``.

Where today's options are not re-expressed as terms: ``PushWithObstaclesEnv``'s obstacle modes (``random``,
``curriculum``) place the walls with rules (clear of the start, of each other), not as independent draws per wall:
they stay modes, and ``obstacle_xy`` is the term for fixed layouts; ``std_noise`` / ``object_noise`` are observation
noise, not model fields: :class:`magwarp.envs.sim2real.SensorConfig` (``sensors=``) is their declarative form (on
the trajectory env with the same draws for the same seed; on the push envs in another order).

The planar simulator (trajectory planning) takes the same terms over its own fields
(:mod:`magwarp.envs.planar_randomization`), each firing one Warp kernel (the draws and the packing of the body rows)
with Warp's counter-based generator keyed by the env's seed (not the torch generator: other draws than the push envs'
for the same seed); :data:`PRESETS` names sets of terms per backend (``randomization="sim2real"``).

Plain mappings work too (``--env-kwargs`` JSON): ``{"field": "object_mass", "dist": {"type": "uniform", "lo": 0.2,
"hi": 0.4}, "op": "set", "mode": "reset"}``, or the distribution as ``{"uniform": [0.2, 0.4]}``,
``{"log_uniform": [lo, hi]}``, ``{"gaussian": [mean, std], "clip": [lo, hi]}``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import mujoco
import numpy as np
import torch
import warp as wp

from magwarp._checks import stiffness_limit

__all__ = ["FIELDS", "PRESETS", "EventRunner", "EventTerm", "Gaussian", "LogUniform", "Randomizer", "Uniform", "as_terms",
           "object_ranges_from_terms"]

OPS = ("set", "scale", "add")
MODES = ("startup", "reset", "interval")


def _finite(value, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return v


def _check_interval(dist, positive: bool) -> None:
    """Validate and store ``dist.lo``/``dist.hi`` as floats: finite, ``lo <= hi`` (and ``0 < lo`` if ``positive``)."""
    kind = type(dist).__name__
    lo, hi = _finite(dist.lo, f"{kind}.lo"), _finite(dist.hi, f"{kind}.hi")
    if lo > hi or (positive and lo <= 0):
        raise ValueError(f"{kind} needs {'0 < ' if positive else ''}lo <= hi, got lo={dist.lo!r}, hi={dist.hi!r}")
    object.__setattr__(dist, "lo", lo)
    object.__setattr__(dist, "hi", hi)


@dataclasses.dataclass(frozen=True)
class Uniform:
    """Uniform on ``[lo, hi]``."""

    lo: float
    hi: float

    def __post_init__(self):
        _check_interval(self, positive=False)

    def support(self) -> tuple[float, float]:
        return self.lo, self.hi

    def sample(self, shape: tuple[int, ...], gen: torch.Generator, device, dtype=torch.float32) -> torch.Tensor:
        return torch.empty(shape, device=device, dtype=dtype).uniform_(self.lo, self.hi, generator=gen)


@dataclasses.dataclass(frozen=True)
class LogUniform:
    """``exp(U(log lo, log hi))`` with ``0 < lo <= hi`` (scales spread evenly in ratio)."""

    lo: float
    hi: float

    def __post_init__(self):
        _check_interval(self, positive=True)

    def support(self) -> tuple[float, float]:
        return self.lo, self.hi

    def sample(self, shape: tuple[int, ...], gen: torch.Generator, device, dtype=torch.float32) -> torch.Tensor:
        x = torch.empty(shape, device=device, dtype=dtype)
        return x.uniform_(math.log(self.lo), math.log(self.hi), generator=gen).exp_()


@dataclasses.dataclass(frozen=True)
class Gaussian:
    """Normal ``N(mean, std^2)``; ``clip=(lo, hi)`` clamps the draws (only when given)."""

    mean: float
    std: float
    clip: tuple[float, float] | None = None

    def __post_init__(self):
        object.__setattr__(self, "mean", _finite(self.mean, "Gaussian.mean"))
        std = _finite(self.std, "Gaussian.std")
        if std < 0:
            raise ValueError(f"Gaussian.std must be >= 0, got {self.std!r}")
        object.__setattr__(self, "std", std)
        if self.clip is not None:
            try:
                lo, hi = self.clip
            except (TypeError, ValueError):
                raise ValueError(f"Gaussian.clip must be a pair (lo, hi), got {self.clip!r}") from None
            lo, hi = _finite(lo, "Gaussian.clip[0]"), _finite(hi, "Gaussian.clip[1]")
            if lo > hi:
                raise ValueError(f"Gaussian.clip needs lo <= hi, got {self.clip!r}")
            object.__setattr__(self, "clip", (lo, hi))

    def support(self) -> tuple[float, float]:
        return self.clip if self.clip is not None else (-math.inf, math.inf)

    def sample(self, shape: tuple[int, ...], gen: torch.Generator, device, dtype=torch.float32) -> torch.Tensor:
        x = torch.empty(shape, device=device, dtype=dtype).normal_(self.mean, self.std, generator=gen)
        return x if self.clip is None else x.clamp_(*self.clip)


Distribution = Uniform | LogUniform | Gaussian
_DISTS = {"uniform": Uniform, "log_uniform": LogUniform, "loguniform": LogUniform, "gaussian": Gaussian,
          "normal": Gaussian}


def as_distribution(value, where: str = "dist") -> Distribution:
    """A distribution from itself or a mapping (``{"type": "uniform", "lo": .., "hi": ..}`` or ``{"uniform": [lo,
    hi]}``, ``{"gaussian": [mean, std], "clip": [lo, hi]}``)."""
    if isinstance(value, (Uniform, LogUniform, Gaussian)):
        return value
    if not isinstance(value, Mapping):
        raise ValueError(f"{where} must be Uniform, LogUniform, Gaussian or a mapping, got {value!r}")
    d = dict(value)
    kind = d.pop("type", None)
    if kind is None:
        keys = [k for k in d if k in _DISTS]
        if len(keys) != 1:
            raise ValueError(f"{where} must name one distribution ({', '.join(_DISTS)}), got {value!r}")
        kind = keys[0]
        args = d.pop(kind)
        if not isinstance(args, (list, tuple)):
            raise ValueError(f"{where}[{kind!r}] must be a list of parameters, got {args!r}")
        return _build_dist(kind, args, d, where, value)
    if kind not in _DISTS:
        raise ValueError(f"{where} has an unknown distribution type {kind!r}; known: {', '.join(_DISTS)}")
    return _build_dist(kind, (), d, where, value)


def _build_dist(kind, args, kwargs, where, value) -> Distribution:
    try:
        return _DISTS[kind](*args, **kwargs)
    except TypeError as e:
        raise ValueError(f"{where}: bad parameters for {kind!r} in {value!r} ({e})") from None


@dataclasses.dataclass(frozen=True)
class EventTerm:
    """One randomisation: ``field`` <- ``op``(nominal, draw from ``dist``) when ``mode`` says.

    ``targets``: indices of the field's targets (movers, objects, obstacles) to change (default: all).
    ``offset``: ``payload_mass`` only, where the payload sits (see the module doc).
    ``known``: ``payload_mass`` only, the controller is configured for the payload it draws: its drive force is
    (mover + payload) x commanded acceleration, so x/y follows the commands (XPlanar's payload parametrisation)."""

    field: str
    dist: Any
    op: str = "set"
    mode: str = "reset"
    interval_steps: int | None = None
    targets: tuple[int, ...] | None = None
    offset: tuple[float, float, float] | None = None
    known: bool = False

    def __post_init__(self):
        if self.field not in FIELDS:
            raise ValueError(f"EventTerm.field {self.field!r} is unknown; known: {', '.join(FIELDS)}")
        object.__setattr__(self, "dist", as_distribution(self.dist, f"EventTerm({self.field!r}).dist"))
        if self.op not in OPS:
            raise ValueError(f"EventTerm({self.field!r}).op must be one of {OPS}, got {self.op!r}")
        spec = FIELDS[self.field]
        if self.op not in spec.ops:
            raise ValueError(f"EventTerm({self.field!r}).op {self.op!r} is not allowed for this field; use one of "
                             f"{spec.ops}")
        if self.mode not in MODES:
            raise ValueError(f"EventTerm({self.field!r}).mode must be one of {MODES}, got {self.mode!r}")
        if self.mode == "interval":
            n = self.interval_steps
            if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
                raise ValueError(f"EventTerm({self.field!r}) in interval mode needs interval_steps >= 1, got {n!r}")
        elif self.interval_steps is not None:
            raise ValueError(f"EventTerm({self.field!r}).interval_steps={self.interval_steps!r} needs mode='interval', "
                             f"got mode={self.mode!r}")
        if self.targets is not None:
            t = tuple(self.targets) if isinstance(self.targets, (list, tuple)) else (self.targets,)
            if not t or not all(isinstance(i, (int, np.integer)) and not isinstance(i, bool) for i in t):
                raise ValueError(f"EventTerm({self.field!r}).targets must be indices, got {self.targets!r}")
            if len(set(t)) != len(t):
                raise ValueError(f"EventTerm({self.field!r}).targets has repeated indices: {self.targets!r}")
            object.__setattr__(self, "targets", tuple(int(i) for i in t))
        if self.offset is not None:
            if self.field != "payload_mass":
                raise ValueError(f"EventTerm({self.field!r}).offset is for 'payload_mass' only, got {self.offset!r}")
            off = tuple(self.offset) if isinstance(self.offset, (list, tuple)) else ()
            if len(off) != 3:
                raise ValueError(f"EventTerm('payload_mass').offset must be (x, y, z) in m, got {self.offset!r}")
            object.__setattr__(self, "offset", tuple(_finite(v, "EventTerm('payload_mass').offset") for v in off))
        if not isinstance(self.known, (bool, np.bool_)):
            raise ValueError(f"EventTerm({self.field!r}).known must be True or False, got {self.known!r}")
        if self.known and self.field != "payload_mass":
            raise ValueError(f"EventTerm({self.field!r}).known is for 'payload_mass' only")


@dataclasses.dataclass(frozen=True)
class FieldSpec:
    """A friendly field: its value per target has ``dim`` components, must stay ``> lower`` (``strict``) or ``>=``."""

    dim: int
    lower: float | None
    strict: bool
    ops: tuple[str, ...]


FIELDS = {
    "object_mass": FieldSpec(1, 0.0, True, OPS),
    "mover_mass": FieldSpec(1, 0.0, True, OPS),
    "payload_mass": FieldSpec(1, 0.0, False, ("set", "add")),
    "object_friction": FieldSpec(1, 0.0, False, OPS),
    "floor_friction": FieldSpec(1, 0.0, False, OPS),
    "obstacle_xy": FieldSpec(2, None, False, ("set", "add")),
    # object sizes (push envs): per episode from object variants, as object_ranges (see object_ranges_from_terms)
    "object_width": FieldSpec(1, 0.0, True, OPS),
    "object_height": FieldSpec(1, 0.0, True, OPS),
    "object_depth": FieldSpec(1, 0.0, True, OPS),
    "object_segment_width": FieldSpec(1, 0.0, True, OPS),
    "object_radius": FieldSpec(1, 0.0, True, OPS),
    # the planar simulator's (magwarp.envs.planar_randomization) and the push backend's control law and checks
    "mover_inertia": FieldSpec(3, 0.0, True, OPS),
    "stiffness_lin": FieldSpec(3, 0.0, False, OPS),
    "stiffness_rot": FieldSpec(3, 0.0, False, OPS),
    "v_max": FieldSpec(1, 0.0, True, OPS),
    "a_max": FieldSpec(1, 0.0, True, OPS),
    "j_max": FieldSpec(1, 0.0, True, OPS),
    "collision_radius": FieldSpec(1, 0.0, True, OPS),
    "collision_half_size": FieldSpec(2, 0.0, True, OPS),
    "collision_margin": FieldSpec(1, 0.0, False, OPS),
    "wall_margin": FieldSpec(1, 0.0, False, OPS),
}

#: Named sets of terms (``randomization="sim2real"``, e.g. from ``--env-kwargs``), per backend: ``"planar"`` (the
#: trajectory-planning env's simulator) or ``"push"`` (the mujoco-warp push envs). All drawn at every reset of a world.
#: Where the planar ranges come from (XPlanar-like; assumptions where no datasheet figure is at hand):
#:
#: * ``mover_mass`` x 0.8 .. 1.25 (log-uniform): the true mass against the one the controller is configured for, i.e. a
#:   gain error of +-20 % on the delivered x/y acceleration (an unconfigured part of the payload, the drive's force
#:   constant over the air gap and temperature). An assumption, on the generous side: XPlanar's drive closes its
#:   position loop around the setpoints the PLC sends, so a mismatch shows as a transient tracking error, not as a
#:   lasting gain error.
#: * ``payload_mass`` 0 .. 0.3 kg on the top surface (6 mm above the centre), ``known``: the payload a real cell
#:   configures (XPlanar's payload parametrisation; Planar Motor's XBot takes ``PayloadWeight`` and its centre of
#:   gravity the same way), so the controller's feedforward includes it and x/y follows the commands; it still moves
#:   the centre of mass, the inertia and the weight the levitation carries. An *unknown* 0.3 kg on the 0.63 kg B0
#:   mover would make it deliver 68 % of every commanded acceleration for the whole episode, which a closed-loop
#:   planar drive does not do (it was the preset until #24's audit; ``known=False`` still models it).
#: * ``stiffness_lin`` / ``stiffness_rot`` x 0.7 .. 1.3: the z/attitude hold is the simulator's impedance law, not
#:   XPlanar's controller; +-30 % covers that model error.
#: * ``a_max`` / ``v_max`` x 0.9 .. 1.0: a drive that delivers a little less than the datasheet's 10 m/s^2, 2 m/s.
#:
#: On the push envs: object mass (0.2 .. 0.4 kg) and friction (0.6 +- 0.1, clipped), mover mass and a known payload of
#: up to 0.3 kg (off centre, 2 cm in x and 1 cm up) as above. Collision sizes are left out: they are safety margins the
#: user sets, not physical tolerances (and starts are sampled with the built sizes, see
#: :mod:`magwarp.envs.planar_randomization`).
#: Latency and sensor models are env options, not terms (``benchmarks/robustness.py`` says which values it uses).
PRESETS: dict[str, dict[str, list[dict]]] = {
    "sim2real": {
        "planar": [
            {"field": "mover_mass", "dist": {"log_uniform": [0.8, 1.25]}, "op": "scale"},
            {"field": "payload_mass", "dist": {"uniform": [0.0, 0.3]}, "offset": [0.0, 0.0, 0.006], "known": True},
            {"field": "stiffness_lin", "dist": {"uniform": [0.7, 1.3]}, "op": "scale"},
            {"field": "stiffness_rot", "dist": {"uniform": [0.7, 1.3]}, "op": "scale"},
            {"field": "a_max", "dist": {"uniform": [0.9, 1.0]}, "op": "scale"},
            {"field": "v_max", "dist": {"uniform": [0.9, 1.0]}, "op": "scale"},
        ],
        "push": [
            {"field": "object_mass", "dist": {"uniform": [0.2, 0.4]}},
            {"field": "object_friction", "dist": {"gaussian": [0.6, 0.1], "clip": [0.3, 0.9]}},
            {"field": "mover_mass", "dist": {"log_uniform": [0.8, 1.25]}, "op": "scale"},
            {"field": "payload_mass", "dist": {"uniform": [0.0, 0.3]}, "offset": [0.02, 0.0, 0.01], "known": True},
        ],
    },
}


def as_terms(terms, backend: str | None = None) -> list[EventTerm]:
    """EventTerms from EventTerms or mappings, or a preset's name (:data:`PRESETS`, for ``backend``); names the bad
    entry."""
    if isinstance(terms, str):
        if terms not in PRESETS:
            raise ValueError(f"randomization preset {terms!r} is unknown; known: {', '.join(PRESETS)}")
        if backend not in PRESETS[terms]:
            raise ValueError(f"randomization preset {terms!r} has no terms for the {backend!r} backend; it has "
                             f"{', '.join(PRESETS[terms])}")
        terms = PRESETS[terms][backend]
    if isinstance(terms, (EventTerm, Mapping)) or not isinstance(terms, Sequence):
        raise ValueError(f"randomization must be a list of EventTerm (or mappings) or a preset name, got {terms!r}")
    out = []
    for i, t in enumerate(terms):
        if isinstance(t, EventTerm):
            out.append(t)
        elif isinstance(t, Mapping):
            try:
                out.append(EventTerm(**t))
            except TypeError as e:
                raise ValueError(f"randomization[{i}] = {dict(t)!r}: {e}") from None
        else:
            raise ValueError(f"randomization[{i}] must be an EventTerm or a mapping, got {t!r}")
    return out


#: the push control law's per-world fields (:meth:`magwarp.physics.MjwBackend.batch_control`) and the per-cycle
#: collision check's (:meth:`magwarp.physics.mover_checks.MoverChecks.per_world`)
CONTROL_FIELDS = ("stiffness_lin", "stiffness_rot", "v_max", "a_max", "j_max")
COLLISION_FIELDS = ("collision_radius", "collision_half_size", "collision_margin", "wall_margin")

#: object size fields -> ``object_ranges`` keys
OBJECT_SIZE_FIELDS = {"object_width": "width", "object_height": "height", "object_depth": "depth",
                      "object_segment_width": "segment_width", "object_radius": "radius"}


def object_ranges_from_terms(terms: list[EventTerm]) -> tuple[list[EventTerm], dict[str, tuple[float, float]]]:
    """Split the object size terms off ``terms`` as ``object_ranges`` (the push envs' per-episode object variants,
    :mod:`magwarp.envs.object_variants`): ``EventTerm("object_width", Uniform(lo, hi))`` (op ``set``, mode ``reset``)
    is ``object_ranges={"width": (lo, hi)}``, with the same draws for the same seed. Sizes change the object's
    geometry, which mujoco-warp's collision, the coverage tables and the start sampling read, so they come from
    ``object_variants`` pre-compiled variants (a pool, not a continuous draw per world): other distributions,
    operations or modes are refused, naming the term. With size terms, an ``object_mass`` term of that form is the
    variants' ``"mass"`` range too (``object_ranges={"width": .., "mass": ..}``, the same draws); without them it stays
    a continuous per-world draw (:class:`Randomizer`; other draws than ``object_ranges={"mass": ..}``)."""
    rest, ranges = [], {}
    sizes = any(t.field in OBJECT_SIZE_FIELDS for t in terms)
    for i, t in enumerate(terms):
        key = OBJECT_SIZE_FIELDS.get(t.field)
        if key is None and sizes and t.field == "object_mass":
            key = "mass"
        if key is None:
            rest.append(t)
            continue
        if not isinstance(t.dist, Uniform) or t.op != "set" or t.mode != "reset" or t.targets not in (None, (0,)):
            raise ValueError(f"randomization[{i}] ({t.field!r}): object sizes (and, with them, the object's mass) are "
                             f"drawn per episode from object variants (object_ranges): a uniform distribution, op "
                             f"'set', mode 'reset' only; got {t.dist!r}, op {t.op!r}, mode {t.mode!r}")
        if key in ranges:
            raise ValueError(f"randomization[{i}] ({t.field!r}) repeats an object size term")
        ranges[key] = (t.dist.lo, t.dist.hi)
    return rest, ranges


def _apply_op(op: str, nominal: torch.Tensor, draw: torch.Tensor) -> torch.Tensor:
    """The new value from a fresh ``draw`` (overwritten: one op at most, none for ``set``)."""
    return draw if op == "set" else draw.mul_(nominal) if op == "scale" else draw.add_(nominal)


def _geom_ids(mjm: mujoco.MjModel, prefix: str) -> list[int]:
    out = []
    for g in range(mjm.ngeom):
        name = mujoco.mj_id2name(mjm, mujoco.mjtObj.mjOBJ_GEOM, g) or ""
        if name.startswith(prefix):
            out.append(g)
    return out


class EventRunner:
    """Fires a list of :class:`EventTerm` per world (the bookkeeping common to every backend): ``values[field]``, the
    current value per world and target (``[W, T]``, ``[W, T, dim]`` for fields of several components), and
    ``nominal[field]``, the built model's (``[T]`` / ``[T, dim]``). A backend's subclass says which fields it has
    (:attr:`BACKEND`, :meth:`_resolve_targets`, :meth:`_nominal`), prepares its model (:meth:`_prepare`) and writes
    the values into it (:meth:`commit`)."""

    BACKEND = ""
    #: ``[W, M]``, the payload the controller is configured for (``EventTerm.known``), where the backend has one
    payload_known: torch.Tensor | None = None

    def __init__(self, env, terms, num_worlds: int, device):
        self.terms = as_terms(terms, self.BACKEND)
        self.env = env
        self.num_worlds, self.device = num_worlds, device
        used = {t.field for t in self.terms}
        self._targets = self._resolve_targets(env, used)
        for i, t in enumerate(self.terms):
            if t.field not in self._targets:
                raise ValueError(f"randomization[{i}] field {t.field!r} is not one of this env's ({self.BACKEND} "
                                 f"backend): {', '.join(self._targets)}")
            count = self._targets[t.field]
            if count == 0:
                raise ValueError(f"randomization[{i}] targets {t.field!r}, but this env has none")
            if t.targets is not None and not all(0 <= k < count for k in t.targets):
                raise ValueError(f"randomization[{i}] ({t.field!r}).targets {t.targets!r} out of range: this env has "
                                 f"{count}")
        self.nominal = self._nominal()
        for i, t in enumerate(self.terms):
            self._check_bounds(i, t)  # before anything on the device changes
        self._prepare(used)
        self.values = self._initial_values(used)
        self._terms_idx = [None if t.targets is None else torch.tensor(t.targets, device=self.device)
                           for t in self.terms]
        self._offsets = [None if t.offset is None else torch.tensor(t.offset, device=self.device) for t in self.terms]
        self.steps = 0
        self._fire("startup", None)
        self.commit(None)

    def _resolve_targets(self, env, used) -> dict[str, int]:
        raise NotImplementedError

    def _nominal(self) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    def _prepare(self, used: set[str]) -> None:
        """Make the model's arrays per world where the terms need it (after every check passed)."""

    def _initial_values(self, used: set[str]) -> dict[str, torch.Tensor]:
        """``values`` (the nominal ones in every world) and ``payload_offset`` (``[W, M, 3]``, zero)."""
        if "payload_mass" in used:
            self.payload_offset = torch.zeros(self.num_worlds, self._targets["payload_mass"], 3, device=self.device)
            self.payload_known = torch.zeros(self.num_worlds, self._targets["payload_mass"], device=self.device)
        return {f: self.nominal[f].expand(self.num_worlds, *self.nominal[f].shape).clone() for f in used}

    def commit(self, mask: torch.Tensor | None) -> None:
        raise NotImplementedError

    def extreme(self, t: EventTerm) -> tuple[float, float]:
        """The least and the largest value ``t`` can give (over its targets' nominal values)."""
        lo, hi = t.dist.support()
        nom = self.nominal[t.field]
        if t.targets is not None:
            nom = nom[list(t.targets)]
        nom = nom.reshape(-1).cpu().numpy().astype(np.float64)
        with np.errstate(invalid="ignore"):
            if t.op == "set":
                return lo, hi
            if t.op == "add":
                return float(nom.min()) + lo, float(nom.max()) + hi
            ends = np.concatenate([nom * lo, nom * hi])
            return float(np.min(ends)), float(np.max(ends))

    def _check_bounds(self, i: int, t: EventTerm) -> None:
        spec = FIELDS[t.field]
        if spec.lower is None:
            return
        least = self.extreme(t)[0]
        bad = least <= spec.lower if spec.strict else least < spec.lower
        if bad or not np.isfinite(least):
            rel = ">" if spec.strict else ">="
            hint = " (a Gaussian needs clip=(lo, hi) to bound it)" if isinstance(t.dist, Gaussian) else ""
            raise ValueError(f"randomization[{i}] ({t.field!r}, op {t.op!r}, {t.dist!r}) can make {t.field} "
                             f"{least:g}, but it must stay {rel} {spec.lower:g}{hint}")

    def check_stiffness_stable(self, i: int, t: EventTerm, dt: float, mass: float, inertia: float) -> None:
        """Refuse a stiffness term whose largest value is unstable at ``dt`` for the lightest mover the terms allow
        (``mass`` / ``inertia``: the built mover's, the least principal moment for ``stiffness_rot``)."""
        rot = t.field == "stiffness_rot"
        field = "mover_inertia" if rot else "mover_mass"
        drawn = [self.extreme(u)[0] for u in self.terms if u.field == field]
        least = min([float(self.nominal[field].min()) if field in self.nominal else np.inf,
                     inertia if rot else mass, *drawn])
        top, limit = self.extreme(t)[1], stiffness_limit(least, dt)
        if not top < limit:
            raise ValueError(f"randomization[{i}] ({t.field!r}) can make the stiffness {top:g}, unstable at dt = "
                             f"{dt:g} s for a mover of {least:.4g} {'kg m^2' if rot else 'kg'} (the stable limit is "
                             f"{limit:.4g}, K < M (0.828 / dt)^2)")

    # ------------------------------------------------------------------ events
    def reset(self, mask: torch.Tensor) -> None:
        """Reset-mode terms for the worlds in ``mask``; rewrites their randomised model entries (after a reset that
        changed model rows, e.g. object variants)."""
        self._fire("reset", mask)
        self.commit(mask)

    def step(self) -> None:
        """Count an env step; interval terms whose period divides the count fire (all worlds)."""
        self.steps += 1
        if self._fire("interval", None):
            self.commit(None)

    def _fire(self, mode: str, mask: torch.Tensor | None) -> bool:
        fired = False
        for i, t in enumerate(self.terms):
            if t.mode != mode or (mode == "interval" and self.steps % t.interval_steps):
                continue
            fired = True
            idx = self._terms_idx[i]
            nom = self.nominal[t.field] if idx is None else self.nominal[t.field][idx]
            cur = self.values[t.field]  # drawn in its dtype (the planar body fields: float64)
            draw = t.dist.sample((self.num_worlds, *nom.shape), self.env._generator, self.device, cur.dtype)
            new = _apply_op(t.op, nom, draw)
            # few ops: every reset of every step runs this (autoreset), for the reset worlds (often none)
            if idx is None:
                if mask is None:
                    cur.copy_(new)
                else:
                    torch.where(mask.view(-1, *([1] * (new.dim() - 1))), new, cur, out=cur)
            else:
                old = cur[:, idx]
                if mask is not None:
                    new = torch.where(mask.view(-1, *([1] * (new.dim() - 1))), new, old)
                cur[:, idx] = new.to(cur.dtype)
            if t.field == "payload_mass":
                off = self._offsets[i] if self._offsets[i] is not None else torch.zeros(3, device=self.device)
                po = self.payload_offset if idx is None else self.payload_offset[:, idx]
                po_new = off.to(po.dtype).expand_as(po)
                if mask is not None:
                    po_new = torch.where(mask.view(-1, 1, 1), po_new, po)
                if idx is None:
                    self.payload_offset.copy_(po_new)
                else:
                    self.payload_offset[:, idx] = po_new
                if self.payload_known is not None:  # the controller's configured payload: the draw or none
                    pk = self.payload_known if idx is None else self.payload_known[:, idx]
                    pk_new = new.to(pk.dtype) if t.known else torch.zeros_like(pk)
                    if mask is not None:
                        pk_new = torch.where(mask.view(-1, 1), pk_new, pk)
                    if idx is None:
                        self.payload_known.copy_(pk_new)
                    else:
                        self.payload_known[:, idx] = pk_new
        return fired


class Randomizer(EventRunner):
    """Applies a list of :class:`EventTerm` to a push env's mujoco-warp backend, per world (see the module doc).

    ``values[field]``: the current value per world and target (``[W, T]``, ``obstacle_xy``: ``[W, T, 2]``);
    ``nominal[field]``: the built model's (``[T]`` / ``[T, 2]``)."""

    BACKEND = "push"

    def __init__(self, env, terms):
        self.backend = env.backend
        super().__init__(env, terms, env.backend.num_worlds, env.backend.torch_device)

    def _prepare(self, used: set[str]) -> None:
        b = self.backend
        mjm = b.mjm
        names = set()
        if used & {"object_mass", "mover_mass", "payload_mass"}:
            names |= {"body_mass", "body_subtreemass", "body_inertia", "body_ipos", "body_invweight0", "dof_invweight0"}
        if used & {"object_friction", "floor_friction"}:
            names.add("geom_friction")
        if "obstacle_xy" in used:
            names.add("geom_pos")
        if "mover_inertia" in used:
            names |= {"body_mass", "body_subtreemass", "body_inertia", "body_ipos", "body_invweight0", "dof_invweight0"}
        self.fields = b.batch_model_fields(sorted(names))
        if "floor_friction" in used:
            self._floor_priority(mjm)
        self._known = any(t.known for t in self.terms)
        self.control = b.batch_control() if used & set(CONTROL_FIELDS) or self._known else None
        if self.control is not None:
            self._law_mass = self.control["mass"][0].clone()  # the built mover's (the law's nominal)
        self.collision = self.env.checks.per_world() if used & set(COLLISION_FIELDS) else None
        for i, t in enumerate(self.terms):
            if t.field in ("stiffness_lin", "stiffness_rot"):
                mass = float(self._body_nominal["mover"]["mass"].min()) if b.num_movers else np.inf
                inertia = float(self._body_nominal["mover"]["inertia"].min()) if b.num_movers else np.inf
                self.check_stiffness_stable(i, t, b.dt, mass, inertia)

    # ------------------------------------------------------------------ construction
    def _resolve_targets(self, env, used) -> dict[str, int]:
        b, mjm = self.backend, self.backend.mjm
        if "object_mass" in used and getattr(env, "variants", None) is not None:
            raise ValueError("randomization of 'object_mass' with a varying object_ranges: its object variants set "
                             "the object's mass rows at every reset; use object_ranges' 'mass' range instead")
        if "obstacle_xy" in used and getattr(env, "_varying_walls", lambda: False)():
            raise ValueError(f"randomization of 'obstacle_xy' with obstacle_mode={env.obstacle_mode!r}: that mode "
                             "already moves the walls per episode; use a fixed mode ('simple', 'medium', 'hard')")
        self.object_geoms = [_geom_ids(mjm, f"object_{k}_geom_") for k in range(b.num_objects)]
        self.floor_geoms = [g for g in _geom_ids(mjm, "tile_")
                            if mjm.geom_contype[g] or mjm.geom_conaffinity[g]]
        self.obstacle_geoms = _geom_ids(mjm, "obstacle_geom_")
        for g in self.obstacle_geoms:
            if mjm.body_weldid[mjm.geom_bodyid[g]] != 0:
                raise ValueError(f"obstacle geom {g} is not attached to the world body; obstacle_xy moves static geoms")
        m = b.num_movers
        checks = getattr(env, "checks", None)
        circle = checks is not None and env.mover.collision_shape == "circle"
        box = checks is not None and not circle
        out = {"object_mass": b.num_objects, "mover_mass": m, "payload_mass": m, "mover_inertia": m,
               "object_friction": b.num_objects, "floor_friction": int(bool(self.floor_geoms)),
               "obstacle_xy": len(self.obstacle_geoms), "collision_radius": m if circle else 0,
               "collision_half_size": m if box else 0, "collision_margin": int(checks is not None),
               "wall_margin": int(checks is not None)}
        out.update({f: m for f in CONTROL_FIELDS})
        return out

    def _floor_priority(self, mjm) -> None:
        """Give the floor contact priority over the object, with the object's contact parameters as nominal."""
        if not self.object_geoms or not self.object_geoms[0]:
            raise ValueError("floor_friction needs an object whose contacts with the floor it sets; this env has none")
        src = self.object_geoms[0][0]
        bad = [g for g in self.floor_geoms if mjm.geom_condim[g] != mjm.geom_condim[src]]
        if bad:
            raise ValueError(f"floor_friction: the floor geoms {bad} have condim {mjm.geom_condim[bad[0]]}, the object "
                             f"{mjm.geom_condim[src]}; give them the same condim")
        m = self.backend.model
        floor = torch.tensor(self.floor_geoms, device=self.device)
        wp.to_torch(m.geom_priority)[floor] = int(mjm.geom_priority.max()) + 1
        for name in ("geom_solref", "geom_solimp", "geom_friction"):
            arr = self.fields.get(name) if name in self.fields else wp.to_torch(getattr(m, name))
            arr[:, floor] = arr[:, src:src + 1].clone()

    def _nominal(self) -> dict[str, torch.Tensor]:
        """The compiled model's values (``backend.mjm``), whatever the device arrays hold now."""
        b, mjm, dev = self.backend, self.backend.mjm, self.device

        def t(x):
            return torch.as_tensor(np.asarray(x, np.float32), device=dev)

        out = {"object_mass": t(mjm.body_mass[b.object_body]), "mover_mass": t(mjm.body_mass[b.mover_body]),
               "payload_mass": torch.zeros(b.num_movers, device=dev)}
        # subtree[:, b] = sum of body_mass over b's subtree: body_mass @ inside, inside[j, b] = j lies under b
        inside = np.zeros((mjm.nbody, mjm.nbody), np.float32)
        for j in range(mjm.nbody):
            body = j
            while True:
                inside[j, body] = 1.0
                if body == 0:
                    break
                body = mjm.body_parentid[body]
        self._subtree = t(inside)
        self._body_nominal = {}
        for group, bodies, dadr in (("object", b.object_body, b.object_dadr), ("mover", b.mover_body, b.mover_dadr)):
            dofs = np.asarray(dadr, np.int64).reshape(-1, 1) + np.arange(6)
            rot = np.stack([_quat_mat(q) for q in mjm.body_iquat[bodies]]) if len(bodies) else np.zeros((0, 3, 3))
            self._body_nominal[group] = {
                "bodies": torch.as_tensor(bodies, device=dev).long(), "dofs": torch.as_tensor(dofs, device=dev),
                "mass": t(mjm.body_mass[bodies]), "inertia": t(mjm.body_inertia[bodies]),
                "ipos": t(mjm.body_ipos[bodies]), "invweight": t(mjm.body_invweight0[bodies]),
                "dof_invweight": t(mjm.dof_invweight0[dofs]), "rot": t(rot),
            }
        src = [g[0] for g in self.object_geoms]
        out["object_friction"] = t(mjm.geom_friction[src, 0])
        # the floor's nominal friction is the object's (see _floor_priority)
        out["floor_friction"] = t(mjm.geom_friction[src[:1], 0]) if self.floor_geoms else torch.zeros(0, device=dev)
        self._geom_owner = {
            "object_friction": self._owner_index(self.object_geoms),
            "floor_friction": self._owner_index([self.floor_geoms]),
        }
        out["obstacle_xy"] = t(mjm.geom_pos[self.obstacle_geoms, :2].reshape(-1, 2))
        out["mover_inertia"] = t(mjm.body_inertia[b.mover_body].reshape(-1, 3))
        c, m = b.control, b.num_movers
        out.update({"stiffness_lin": t(np.tile(c.k_lin, (m, 1))), "stiffness_rot": t(np.tile(c.k_rot, (m, 1))),
                    "v_max": t(np.full(m, c.v_max)), "a_max": t(np.full(m, c.a_max)), "j_max": t(np.full(m, c.j_max))})
        mover = getattr(self.env, "mover", None)
        if mover is not None:
            out.update({"collision_radius": t(np.full(m, mover.collision_radius)),
                        "collision_half_size": t(np.tile(mover.collision_half_size, (m, 1))),
                        "collision_margin": t([mover.margin]), "wall_margin": t([mover.wall_margin])})
        self._obstacle_index = torch.as_tensor(self.obstacle_geoms, device=dev, dtype=torch.long)
        return out

    def _owner_index(self, groups: list[list[int]]) -> tuple[torch.Tensor, torch.Tensor]:
        geoms = [g for grp in groups for g in grp]
        owner = [k for k, grp in enumerate(groups) for _ in grp]
        return (torch.tensor(geoms, device=self.device, dtype=torch.long),
                torch.tensor(owner, device=self.device, dtype=torch.long))

    # ------------------------------------------------------------------ model writes
    def commit(self, mask: torch.Tensor | None) -> None:
        """Write the current values into the model arrays for the worlds in ``mask`` (all if None)."""
        v = self.values
        if "object_mass" in v:
            self._commit_bodies("object", v["object_mass"], None, None, mask)
        if "mover_mass" in v or "payload_mass" in v or "mover_inertia" in v:
            mass = v.get("mover_mass", self.nominal["mover_mass"].expand(self.num_worlds, -1))
            pay = v.get("payload_mass")
            self._commit_bodies("mover", mass, pay, self.payload_offset if pay is not None else None, mask,
                                own_inertia=v.get("mover_inertia"))
        if self._known:
            _put(self.control["mass"], (slice(None),), self._law_mass + self.payload_known, mask)
        if self.control is not None:
            gains, limits = self.control["gains"], self.control["limits"]
            for col, (field, k) in enumerate((("stiffness_lin", 2), ("stiffness_rot", 0), ("stiffness_rot", 1),
                                              ("stiffness_rot", 2))):
                if field in v:
                    _put(gains, (slice(None), slice(None), col), v[field][..., k], mask)
            for col, field in enumerate(("v_max", "a_max", "j_max")):
                if field in v:
                    _put(limits, (slice(None), slice(None), col), v[field], mask)
        if self.collision is not None:
            for field, key, index in (("collision_radius", "radius", ()), ("collision_half_size", "half_size", ()),
                                      ("collision_margin", "margins", (0,)), ("wall_margin", "margins", (1,))):
                if field in v:
                    value = v[field][:, 0] if index else v[field]
                    _put(self.collision[key], (slice(None), *index), value, mask)
        for name in ("object_friction", "floor_friction"):
            if name in v:
                geoms, owner = self._geom_owner[name]
                fr = self.fields["geom_friction"]
                _put(fr, (slice(None), geoms, 0), v[name][:, owner], mask)
        if "obstacle_xy" in v:
            g = self._obstacle_index
            _put(self.fields["geom_pos"], (slice(None), g, slice(0, 2)), v["obstacle_xy"], mask)
            xpos = wp.to_torch(self.backend.data.geom_xpos)
            _put(xpos, (slice(None), g, slice(0, 2)), v["obstacle_xy"], mask)
            boxes = getattr(self.env, "obstacle_boxes", None)
            if boxes is not None and boxes.shape[1] == len(self.obstacle_geoms):
                _put(boxes, (slice(None), slice(None), slice(0, 2)), v["obstacle_xy"], mask)

    def _commit_bodies(self, group: str, mass, payload, offset, mask, own_inertia=None) -> None:
        n, f = self._body_nominal[group], self.fields
        bi = n["bodies"]
        s = mass / n["mass"]  # uniform-density scale of the body itself (unless its inertia is randomised too)
        inertia = s[..., None] * n["inertia"] if own_inertia is None else own_inertia
        ipos = n["ipos"].expand(mass.shape[0], -1, -1)
        total = mass
        if payload is not None:
            total = mass + payload
            mu = (mass * payload / total)[..., None]
            r = torch.einsum("tji,wtj->wti", n["rot"], offset)  # into the principal (iquat) frame
            inertia = inertia + mu * ((r * r).sum(-1, keepdim=True) - r * r)
            ipos = ipos + (payload / total)[..., None] * offset
        _put(f["body_mass"], (slice(None), bi), total, mask)
        _put(f["body_subtreemass"], (slice(None),), f["body_mass"] @ self._subtree, mask)
        _put(f["body_inertia"], (slice(None), bi), inertia, mask)
        _put(f["body_ipos"], (slice(None), bi), ipos, mask)
        rot_ratio = (1.0 / inertia).mean(-1) / (1.0 / n["inertia"]).mean(-1)
        lin_ratio = n["mass"] / total
        iw = n["invweight"] * torch.stack([lin_ratio, rot_ratio], -1)
        _put(f["body_invweight0"], (slice(None), bi), iw, mask)
        ratios = torch.cat([lin_ratio[..., None].expand(-1, -1, 3), rot_ratio[..., None].expand(-1, -1, 3)], -1)
        _put(f["dof_invweight0"], (slice(None), n["dofs"]), n["dof_invweight"] * ratios, mask)


def _put(dst: torch.Tensor, index: tuple, value: torch.Tensor, mask: torch.Tensor | None) -> None:
    """``dst[index] = value`` for the worlds in ``mask`` (all if None); the leading axis is the world."""
    if mask is not None:
        old = dst[index]
        value = torch.where(mask.view(-1, *([1] * (old.dim() - 1))), value.expand_as(old), old)
    dst[index] = value


def _quat_mat(q) -> np.ndarray:
    """Rotation matrix of a MuJoCo quaternion (w, x, y, z)."""
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, np.float64))
    return m.reshape(3, 3)
