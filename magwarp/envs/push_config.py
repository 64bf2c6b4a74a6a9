"""The push envs' options as typed config dataclasses (:mod:`magwarp.envs.config`): :class:`PushConfig` holds every
option of :class:`~magwarp.envs.push.PushEnv` and checks them all in ``__post_init__``, before any model is built;
:class:`PushBoxConfig`, :class:`PushTConfig`, :class:`PushLConfig` and :class:`PushXConfig` are the benchmark tasks'
(their object and episode length). The obstacle and cooperative tasks' configs live beside their envs
(:class:`~magwarp.envs.push_obstacles.PushWithObstaclesConfig`, :class:`~magwarp.envs.coop_push.CoopPushConfig`).

A subclass whose options stand for other push options (an alias, values derived from its own fields) says so in
:meth:`PushConfig.as_push_config`: the plain :class:`PushConfig` the env is built from, checked like any other::

    cfg = PushConfig(object_type="t_shape", learn_pose=True, max_episode_steps=50)
    env = PushEnv(4096, cfg, device="cuda:0")
    env2 = PushEnv(4096, cfg, min_coverage=0.95)           # the same config with one field changed
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from magwarp._checks import as_count, as_flag, check_finite, check_magnitude
from magwarp.envs.config import make_mover_spec
from magwarp.envs.object_variants import check_ranges
from magwarp.envs.randomization import EventTerm, as_terms, object_ranges_from_terms
from magwarp.envs.sim2real import ActuationConfig, SensorConfig, as_config, check_noise_or_sensors
from magwarp.layout import Layout, MoverSpec
from magwarp.mjcf import ObjectSpec, ObstacleSpec
from magwarp.physics import ControlParams
from magwarp.physics.backend import physics_substeps

__all__ = ["PUSH_BENCHMARKS", "PushConfig", "PushBoxConfig", "PushTConfig", "PushLConfig", "PushXConfig",
           "push_benchmark"]

# MagBotSim's pushing benchmark variants: B0 is a 3 x 3 grid with one mover; B1..B9 use the trajectory planning
# benchmark layouts (magwarp.layout) with 1, 1, 2, 2, 2, 2, 2, 2, 2 movers.
PUSH_BENCHMARKS = tuple(f"B{i}" for i in range(10))
_PUSH_BENCHMARK_MOVERS = (1, 1, 1, 2, 2, 2, 2, 2, 2, 2)
SOLVERS = ("auto", "Newton", "CG")


def push_benchmark(name: str) -> tuple[Layout, int]:
    """Layout and mover count of pushing benchmark variant ``"B0"``..``"B9"``."""
    from magwarp.layout import benchmark_layout

    if name not in PUSH_BENCHMARKS:
        raise ValueError(f"unknown pushing benchmark {name!r}; choose one of {list(PUSH_BENCHMARKS)}")
    i = PUSH_BENCHMARKS.index(name)
    layout = Layout(np.ones((3, 3), dtype=np.int32)) if i == 0 else benchmark_layout(name)[0]
    return layout, _PUSH_BENCHMARK_MOVERS[i]


@dataclass(frozen=True)
class PushConfig:
    """Options of :class:`~magwarp.envs.push.PushEnv` (the module docstring of :mod:`magwarp.envs.push` says what the
    task does with them). Every field is checked in ``__post_init__``; a bad value raises naming it, before anything
    is built.

    Scene: ``object_type`` is one of ``box``, ``square_box``, ``cylinder``, ``t_shape``, ``l_shape``, ``plus_shape``
    (or ``T``, ``L``, ``X``). ``layout`` is a :class:`~magwarp.layout.Layout` or 0/1 array (default: 4 x 3 tiles);
    ``benchmark`` (``"B0"``..``"B9"``) picks MagBotSim's pushing benchmark layout and mover count instead of
    ``layout`` and ``num_movers``. ``obstacles``: static boxes (:class:`~magwarp.mjcf.ObstacleSpec`) on the tiles.

    Goals: ``learn_pose`` (goal poses scored by coverage, else goal positions), ``max_position_err`` (m, position
    goals' success distance), ``min_coverage`` (in [0, 1], pose goals' success coverage; the paper's 0.7, MagBotSim's
    library uses 0.95).

    Action: ``learn_jerk`` (jerk instead of acceleration commands), ``v_max`` / ``a_max`` / ``j_max`` (the movers'
    x/y limits), ``learn_mover_c_rotation`` (each mover's yaw is commanded too, MagBotSim's option), with the yaw
    limits ``p_max_c`` (rad; None: unlimited), ``v_max_c``, ``a_max_c``, ``j_max_c`` (:mod:`magwarp.physics.control`).

    Object: ``object_width``, ``object_height``, ``object_depth``, ``object_segment_width`` and ``object_radius``
    (half-sizes, m), ``object_mass`` (kg), ``object_sliding_friction`` and ``object_torsional_friction``.
    ``object_ranges`` (MagBotSim's): ``{"width": (low, high), ...}`` over ``width``, ``height``, ``depth``,
    ``segment_width``, ``radius`` and ``mass``; a range with low < high gives every episode an object drawn from
    ``object_variants`` samples of the ranges (:mod:`magwarp.envs.object_variants`; ``info["object_variant"]`` says
    which), a fixed one just sets the value.

    Observation noise: ``std_noise`` (mover positions and velocities) and ``object_noise`` (achieved goal), Gaussian
    standard deviations >= 0 (MagBotSim's defaults: 1e-5 each; here 0).

    Reward and episode: ``collision_penalty`` on a mover-mover or wall collision, else ``object_at_goal_reward`` at
    the goal (position goals, or ``use_sparse_pose_reward``), else the coverage where it is positive (dense pose
    reward), else ``per_step_penalty``. ``early_termination_steps``: terminate after that many consecutive steps at
    the goal (None: never); ``max_episode_steps``: truncate after that many env steps.

    Movers: collision options follow MagBotSim's ``collision_params``: ``collision_shape`` (``"circle"`` or
    ``"box"``), ``collision_size`` (radius or x/y half sizes; None: the mover's), ``collision_offset`` (sampling
    margin), ``collision_offset_wall`` (wall margin). ``mover_params`` (MagBotSim's) sets the mover body: ``{"size":
    half sizes (x, y, z), "mass": kg}`` (default: the 155 mm, 1.24 kg APM4330-like box; MagBotSim's published runs
    use 113 mm and 0.639 kg). ``initial_mover_zpos``: the movers' hover gap (m).

    Physics: ``solver`` is MuJoCo's constraint solver for the contacts: ``"Newton"`` (MagBotSim's), ``"CG"``, or
    ``"auto"`` (default): CG on CPU, Newton on CUDA, the faster one on each (benchmarks/RESULTS.md; on a GPU the batch
    waits for its slowest world, and CG's many cheap iterations lose there). Both solve the same elliptic-cone contact
    problem to MuJoCo's tolerance; only the optimiser differs. ``solver_iterations``/``ls_iterations`` cap it (MuJoCo's
    100/50 by default; on a GPU the batch iterates until its slowest world converges, so a low cap is speed bought
    with accuracy in the hardest contacts). ``nconmax``/``njmax`` (contacts and constraint rows per world) default to
    the most the scene can produce: 8 contacts per colliding geom pair, 3 rows per contact.

    Physics step: ``physics_dt`` (s) is mujoco-warp's timestep and the period of the mover control law; an env step
    of ``num_cycles`` control cycles (1 ms each, MagBotSim's and the real system's cycle: 40 ms by default) runs
    ``num_cycles * 1 ms / physics_dt`` physics steps (``substeps``). The default, 0.001, is MagBotSim's. 0.002 (20
    steps per 40 ms env step) is an opt-in fast mode, about 2x the env-steps/s on a GPU: the x/y command law,
    jerk/acceleration integration, velocity cap and impedance hold update every physics step instead of every 1 ms,
    contacts resolve at that step (MuJoCo's contact time constant, 0.02 s, stays above 2 steps, so contact
    stiffness is unchanged), and collisions and the corrective-movement metrics are checked once per physics step.
    Episode lengths and timeouts count env steps and do not change. ``physics_dt`` must divide the env step and lie
    in [:data:`~magwarp.physics.backend.PHYSICS_DT_MIN`, :data:`~magwarp.physics.backend.PHYSICS_DT_MAX`] (0.1 to
    5 ms); see ``docs/push_physics_dt.md`` for what was measured.

    Randomisation and sim2real: ``randomization`` is a list of :class:`magwarp.envs.randomization.EventTerm` (or
    mappings of their fields) that randomise object and mover mass, a payload on the movers, object and floor
    friction and obstacle positions per world, at startup, at each reset (reset worlds only) or every N steps, without
    a model rebuild (:mod:`magwarp.envs.randomization`), or a preset's name (``"sim2real"``); object size terms are
    ``object_ranges`` (give sizes one way, not both). ``actuation`` (action latency,
    :class:`~magwarp.envs.sim2real.ActuationConfig` or a dict of its fields) and ``sensors`` (bias, noise, dropped
    readings of the mover x/y positions and velocities, :class:`~magwarp.envs.sim2real.SensorConfig` or a dict; not
    with ``std_noise`` nor ``learn_mover_c_rotation``) are the sim2real models of :mod:`magwarp.envs.sim2real`."""

    object_type: str = "square_box"
    layout: Layout | np.ndarray | None = None
    num_movers: int = 1
    learn_pose: bool = False
    learn_jerk: bool = False
    learn_mover_c_rotation: bool = False
    p_max_c: float | None = None
    v_max_c: float = 122.17305
    a_max_c: float = 122.17305
    j_max_c: float = 610.86524
    object_width: float = 0.06
    object_height: float = 0.06
    object_depth: float = 0.02
    object_segment_width: float = 0.02
    object_radius: float = 0.05
    object_mass: float = 0.3
    object_sliding_friction: float = 0.6
    object_torsional_friction: float = 0.0001
    object_ranges: Mapping[str, tuple[float, float]] | None = None
    object_variants: int = 64
    std_noise: float = 0.0
    object_noise: float = 0.0
    v_max: float = 2.0
    a_max: float = 10.0
    j_max: float = 100.0
    num_cycles: int = 40
    physics_dt: float = 0.001
    max_position_err: float = 0.05
    min_coverage: float = 0.7
    use_sparse_pose_reward: bool = False
    collision_penalty: float = -10.0
    per_step_penalty: float = -0.01
    object_at_goal_reward: float = 1.0
    early_termination_steps: int | None = None
    max_episode_steps: int = 25
    collision_shape: str = "circle"
    collision_size: float | tuple[float, float] | None = None
    collision_offset: float = 0.0
    collision_offset_wall: float = 0.0
    mover_params: dict | None = None
    initial_mover_zpos: float = 0.003
    obstacles: tuple[ObstacleSpec, ...] = ()
    benchmark: str | None = None
    solver: str = "auto"
    solver_iterations: int = 100
    ls_iterations: int = 50
    nconmax: int | None = None
    njmax: int | None = None
    randomization: Sequence[EventTerm | Mapping[str, Any]] | str | None = None
    actuation: ActuationConfig | dict | None = None
    sensors: SensorConfig | dict | None = None

    def __post_init__(self):
        if self.layout is not None and not isinstance(self.layout, Layout):  # a 0/1 array: checked, kept as a Layout
            object.__setattr__(self, "layout", Layout(self.layout))  # (compared by value: configs stay comparable)
        push = self.as_push_config()  # a subclass's options as plain push options, checked by their own config
        if push is self:
            self._check()

    def as_push_config(self) -> PushConfig:
        """The plain :class:`PushConfig` the env is built from: this config itself; a subclass whose options stand
        for other push options (an alias, a value derived from its own fields) returns them as a :class:`PushConfig`
        (checked as any other)."""
        return self

    def push_fields(self) -> dict[str, Any]:
        """This config's :class:`PushConfig` fields (a subclass's own fields left out)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(PushConfig)}

    # ------------------------------------------------------------------ checks
    def _check(self) -> None:
        """Every option (the first bad one raises, naming it): counts, finite numbers, ranges, flags, the object,
        mover and layout specs, randomisation terms and the sim2real models' configs."""
        if self.benchmark is not None:
            push_benchmark(self.benchmark)
        self.make_layout()
        as_count(self.num_movers, "num_movers")
        if self.collision_shape not in ("circle", "box"):
            raise ValueError(f"collision_shape must be 'circle' or 'box', got {self.collision_shape!r}")
        physics_substeps(self.physics_dt, as_count(self.num_cycles, "num_cycles"))  # a bad physics_dt fails here
        for name in ("max_episode_steps", "solver_iterations", "ls_iterations", "object_variants"):
            as_count(getattr(self, name), name)
        for name in ("nconmax", "njmax", "early_termination_steps"):
            if getattr(self, name) is not None:
                as_count(getattr(self, name), name)
        if self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS} ('auto': CG on CPU, Newton on CUDA), got "
                             f"{self.solver!r}")
        check_finite(p_max_c=self.p_max_c, v_max_c=self.v_max_c, a_max_c=self.a_max_c, j_max_c=self.j_max_c,
                     object_width=self.object_width, object_height=self.object_height,
                     object_depth=self.object_depth, object_segment_width=self.object_segment_width,
                     object_radius=self.object_radius, object_mass=self.object_mass, v_max=self.v_max,
                     a_max=self.a_max, j_max=self.j_max, object_sliding_friction=self.object_sliding_friction,
                     max_position_err=self.max_position_err,
                     object_torsional_friction=self.object_torsional_friction, min_coverage=self.min_coverage,
                     collision_penalty=self.collision_penalty, per_step_penalty=self.per_step_penalty,
                     object_at_goal_reward=self.object_at_goal_reward, collision_size=self.collision_size,
                     collision_offset=self.collision_offset, collision_offset_wall=self.collision_offset_wall,
                     initial_mover_zpos=self.initial_mover_zpos, std_noise=self.std_noise,
                     object_noise=self.object_noise, allow_none=("p_max_c", "collision_size"),
                     vectors=("collision_size",))
        if not 0.0 <= self.min_coverage <= 1.0:
            raise ValueError(f"min_coverage must lie in [0, 1], got {self.min_coverage!r}")
        if not self.max_position_err > 0:
            raise ValueError(f"max_position_err must be positive, got {self.max_position_err!r}")
        self.randomization_terms()  # bad terms, ranges or both ways of giving sizes fail here
        for name in ("learn_pose", "learn_jerk", "learn_mover_c_rotation", "use_sparse_pose_reward"):
            as_flag(getattr(self, name), name)
        for name in ("std_noise", "object_noise"):  # finite: checked above
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be a non-negative number, got {getattr(self, name)!r}")
        check_magnitude(std_noise=self.std_noise, object_noise=self.object_noise)
        self.make_object()
        self.make_mover()
        obstacles = self.obstacles
        if not isinstance(obstacles, (tuple, list)) or not all(isinstance(o, ObstacleSpec) for o in obstacles):
            raise TypeError(f"obstacles must be a tuple of ObstacleSpec, got {obstacles!r}")
        self._check_sim2real()

    def _check_sim2real(self) -> None:
        actuation = as_config(ActuationConfig, self.actuation, "actuation")
        cycles = actuation.latency_cycles
        actuation.delays(1 if np.ndim(cycles) == 0 else np.size(cycles), int(self.num_cycles))  # delay bounds
        if self.sensors is None:
            return
        as_config(SensorConfig, self.sensors, "sensors")
        check_noise_or_sensors(self.std_noise, self.sensors)
        if self.learn_mover_c_rotation:
            raise ValueError("sensors model x/y positions and velocities; not with learn_mover_c_rotation=True")

    # ------------------------------------------------------------------ derived pieces (of a checked config)
    def make_layout(self) -> Layout:
        """The tiles: the benchmark's, ``layout``'s, or 4 x 3 full tiles."""
        if self.benchmark is not None:
            return push_benchmark(self.benchmark)[0]
        if self.layout is None:
            return Layout(np.ones((4, 3), dtype=np.int32))
        return self.layout  # (an array was made a Layout in __post_init__)

    def mover_count(self) -> int:
        """The number of movers: the benchmark's, or ``num_movers``."""
        return push_benchmark(self.benchmark)[1] if self.benchmark is not None else int(self.num_movers)

    def randomization_terms(self) -> tuple[list[EventTerm], dict[str, tuple[float, float]]]:
        """``(terms, object_ranges)``: the randomisation terms other than object sizes, and the checked object
        ranges (``object_ranges``, or the size terms split off ``randomization``)."""
        terms = as_terms(self.randomization, "push") if self.randomization is not None else []
        terms, size_ranges = object_ranges_from_terms(terms)
        ranges = self.object_ranges
        if size_ranges:
            if ranges is not None:
                raise ValueError(f"give object sizes as object_ranges or as randomization terms, not both "
                                 f"object_ranges={ranges!r} and terms for {sorted(size_ranges)}")
            ranges = size_ranges
        return terms, check_ranges(ranges) if ranges is not None else {}

    def varying_ranges(self) -> dict[str, tuple[float, float]]:
        """The object ranges with low < high: every episode draws its object from variants of them."""
        return {k: r for k, r in self.randomization_terms()[1].items() if r[0] < r[1]}

    def make_object(self) -> ObjectSpec:
        """The object the model is built with. Fixed ranges just set the value; varying ones build the model (and
        the sampling margins) with the largest object, and each world then gets one of the variants at every
        reset."""
        obj = ObjectSpec(self.object_type, width=self.object_width, height=self.object_height,
                         depth=self.object_depth, segment_width=self.object_segment_width, radius=self.object_radius,
                         mass=self.object_mass,
                         friction=(self.object_sliding_friction, self.object_torsional_friction, 0.0001))
        return dataclasses.replace(obj, **{k: r[1] for k, r in self.randomization_terms()[1].items()})

    def make_mover(self) -> MoverSpec:
        """The movers' body and collision shape."""
        return make_mover_spec(self.collision_shape, self.collision_size, wall_margin=self.collision_offset_wall,
                               mover_params=self.mover_params, hover_gap=self.initial_mover_zpos)

    def substeps(self) -> int:
        """Physics steps per env step (``num_cycles`` ms at ``physics_dt``)."""
        return physics_substeps(self.physics_dt, int(self.num_cycles))

    def control_params(self) -> ControlParams:
        """The mover drive's limits and command mode (its law runs once per physics step)."""
        return ControlParams(v_max=self.v_max, a_max=self.a_max, j_max=self.j_max,
                             jerk=as_flag(self.learn_jerk, "learn_jerk"), num_cycles=self.substeps(),
                             rotation=as_flag(self.learn_mover_c_rotation, "learn_mover_c_rotation"),
                             v_max_c=self.v_max_c, a_max_c=self.a_max_c, j_max_c=self.j_max_c, p_max_c=self.p_max_c)


def check_object_type(cfg: PushConfig) -> None:
    """A task config whose object is its own (the field's default, aliases such as ``"T"`` included)."""
    want = next(f.default for f in dataclasses.fields(cfg) if f.name == "object_type")
    if cfg.as_push_config().make_object().shape != want:
        name = type(cfg).__name__.removesuffix("Config")
        raise ValueError(f"{name}Env pushes a {want}: object_type must be {want!r}, got {cfg.object_type!r} "
                         f"(PushEnv takes any object_type)")


@dataclass(frozen=True)
class PushBoxConfig(PushConfig):
    """Options of :class:`~magwarp.envs.push.PushBoxEnv` (MagBotSim's Push-Box): :class:`PushConfig`'s with a square
    box (``object_type`` stays ``"square_box"``), position goals and 25 steps by default."""

    def __post_init__(self):
        super().__post_init__()
        check_object_type(self)


@dataclass(frozen=True)
class PushTConfig(PushConfig):
    """Options of :class:`~magwarp.envs.push.PushTEnv` (MagBotSim's Push-T): :class:`PushConfig`'s with a T
    (``object_type`` stays ``"t_shape"``), pose goals (``learn_pose=True``) and 50 steps by default."""

    object_type: str = "t_shape"
    learn_pose: bool = True
    max_episode_steps: int = 50

    def __post_init__(self):
        super().__post_init__()
        check_object_type(self)


@dataclass(frozen=True)
class PushLConfig(PushTConfig):
    """Options of :class:`~magwarp.envs.push.PushLEnv`: :class:`PushTConfig`'s with an L (``"l_shape"``)."""

    object_type: str = "l_shape"


@dataclass(frozen=True)
class PushXConfig(PushTConfig):
    """Options of :class:`~magwarp.envs.push.PushXEnv`: :class:`PushTConfig`'s with an X (``"plus_shape"``)."""

    object_type: str = "plus_shape"
