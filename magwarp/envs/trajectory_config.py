"""The options of :class:`~magwarp.envs.trajectory.TrajectoryPlanningEnv` as one typed, frozen dataclass
(:mod:`magwarp.envs.config`): every option is checked here, before anything is built."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from magwarp._checks import as_count, as_flag, check_finite
from magwarp.envs.config import make_mover_spec
from magwarp.envs.sim2real import SensorConfig, check_noise_or_sensors
from magwarp.layout import Layout, MoverSpec, benchmark_layout, mover_params_kwargs

__all__ = ["TrajectoryConfig", "per_mover_sizes"]


def per_mover_sizes(shape: str, size, num_movers: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """MagBotSim's ``collision_params["size"]`` as per-mover arrays: circle radii ``(M,)`` from one radius or ``(M,)``;
    box half sizes ``(M, 2)`` from one number, ``(2,)`` or ``(M, 2)``. None for the default size."""
    if size is None:
        return None, None
    arr = np.asarray(size, dtype=np.float64)
    shapes = [(), (num_movers,)] if shape == "circle" else [(), (2,), (num_movers, 2)]
    if arr.shape not in shapes or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        what = "radius or per-mover radii" if shape == "circle" else "box half sizes"
        raise ValueError(f"collision_size for a {shape} must be a positive {what} of shape "
                         f"{' or '.join(str(s) for s in shapes)}, got {size!r}")
    if shape == "circle":
        return np.broadcast_to(arr, (num_movers,)).copy(), None
    return None, np.broadcast_to(arr, (num_movers, 2)).copy()


def _frozen(value):
    """A collision size as nested tuples (an array would make the config's ``==`` ambiguous)."""
    if isinstance(value, np.ndarray):
        return _frozen(value.tolist())
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value


@dataclass(frozen=True)
class TrajectoryConfig:
    """Options of :class:`~magwarp.envs.trajectory.TrajectoryPlanningEnv` (MagBotSim's names where it has them).

    * Layout: ``layout`` is a benchmark name (``"B0"``..``"B9"``, each with its mover count), a
      :class:`~magwarp.layout.Layout` or a 0/1 array; ``num_movers`` (None: the benchmark's; required for a custom
      layout).
    * Collisions (MagBotSim's ``collision_params``): ``collision_shape`` (``"circle"`` or ``"box"``),
      ``collision_size`` (radius, or box half sizes (2,); per mover, as MagBotSim allows: radii (num_movers,) or half
      sizes (num_movers, 2), then starts and goals are sampled with the largest; None: the mover's default),
      ``collision_offset`` (safety offset used when sampling starts and goals), ``collision_offset_wall`` (margin
      added for wall checks), ``safety_margin`` (grows every shape in the per-cycle mover-mover check; MagBotSim:
      none; sampled starts keep it too). ``mover_params`` (MagBotSim's): ``{"size": half sizes (x, y, z), "mass":
      kg}``.
    * Control: ``learn_jerk`` (actions are jerks, else accelerations), the limits ``v_max``, ``a_max``, ``j_max``,
      ``num_cycles`` control cycles (1 ms) per env step with the action held; ``force_model``: None (the ideal
      model), ``"magnetic"`` or a :class:`~magwarp.magnetics.MagneticModel`, passed to the simulator.
    * Task: ``threshold_pos`` (m, a goal is reached within it), the rewards ``reward_success`` (per reached goal),
      ``reward_collision``, ``reward_per_step``; ``timeout_steps`` (truncate when no goal was reached for more steps;
      None: never), ``max_episode_steps`` (None, MagBotSim's default: episodes end only on a collision or a timeout;
      training uses it to see episode starts often; the benchmark metrics count a goal pending at this cut as
      neither reached nor failed).
    * Sim2real (:mod:`magwarp.envs.sim2real`): ``std_noise`` (MagBotSim's white noise on positions and velocities:
      ``SensorConfig(pos_noise_std=s, vel_noise_std=s)``), or ``sensors`` (a
      :class:`~magwarp.envs.sim2real.SensorConfig` or a mapping of its fields; not with ``std_noise``),
      ``actuation`` (an :class:`~magwarp.envs.sim2real.ActuationConfig` or mapping: action latency),
      ``randomization`` (event terms or a preset's name, :mod:`magwarp.envs.planar_randomization`).
    * The step (:mod:`magwarp.envs.trajectory_fused`): ``fused`` (the task logic as Warp kernels around the
      simulator's) and ``graph`` (on CUDA the whole step as one captured CUDA graph).

    A bad value raises naming it, in ``__post_init__``: a config that exists is valid, except for what only the
    built env can tell (starts that do not fit the layout, randomisation terms over unknown fields)."""

    layout: Any = "B0"
    num_movers: int | None = None
    collision_shape: str = "circle"
    collision_size: Any = None
    collision_offset: float = 0.0
    collision_offset_wall: float = 0.0
    mover_params: dict | None = None
    safety_margin: float = 0.0
    learn_jerk: bool = False
    v_max: float = 2.0
    a_max: float = 10.0
    j_max: float = 100.0
    num_cycles: int = 40
    threshold_pos: float = 0.1
    reward_success: float = 20.0
    reward_collision: float = -20.0
    reward_per_step: float = -1.0
    timeout_steps: int | None = 50
    max_episode_steps: int | None = None
    std_noise: float = 0.0
    actuation: Any = None
    sensors: Any = None
    randomization: Any = None
    force_model: Any = None
    fused: bool = True
    graph: bool = True

    def __post_init__(self):
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731 - the frozen fields' normal form
        put("fused", as_flag(self.fused, "fused"))
        put("graph", as_flag(self.graph, "graph"))
        put("num_cycles", as_count(self.num_cycles, "num_cycles"))
        put("learn_jerk", as_flag(self.learn_jerk, "learn_jerk"))
        check_finite(threshold_pos=self.threshold_pos, reward_success=self.reward_success,
                     reward_collision=self.reward_collision, reward_per_step=self.reward_per_step,
                     collision_size=self.collision_size, collision_offset=self.collision_offset,
                     collision_offset_wall=self.collision_offset_wall, safety_margin=self.safety_margin,
                     std_noise=self.std_noise, v_max=self.v_max, a_max=self.a_max, j_max=self.j_max,
                     allow_none=("collision_size",), vectors=("collision_size",))
        if self.timeout_steps is not None:
            put("timeout_steps", as_count(self.timeout_steps, "timeout_steps"))
        if not isinstance(self.layout, (str, Layout)):
            put("layout", Layout(self.layout))  # a 0/1 array: checked (and frozen) by the Layout
        self.resolve_layout()  # an unknown benchmark name fails here
        if self.num_movers is not None:
            put("num_movers", as_count(self.num_movers, "num_movers"))
        if self.collision_shape not in ("circle", "box"):
            raise ValueError(f"collision_shape must be 'circle' or 'box', got {self.collision_shape!r}")
        if not self.threshold_pos > 0:
            raise ValueError(f"threshold_pos must be positive, got {self.threshold_pos!r}")
        m = self.max_episode_steps
        if m is not None and (isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 1):
            raise ValueError(f"max_episode_steps must be None or an integer >= 1, got {m!r}")
        if not self.std_noise >= 0:
            raise ValueError(f"std_noise must be a non-negative number, got {self.std_noise!r}")
        check_noise_or_sensors(self.std_noise, self.sensors)
        per_mover_sizes(self.collision_shape, self.collision_size, self.movers)  # a bad size fails here
        put("collision_size", _frozen(self.collision_size))
        mover_params_kwargs(self.mover_params)

    def resolve_layout(self) -> tuple[Layout, int | None, str]:
        """The layout, its benchmark's mover count (None for a custom layout) and its name (``"custom"`` for one
        that is not a benchmark's)."""
        if isinstance(self.layout, str):
            layout, movers = benchmark_layout(self.layout)
            return layout, movers, self.layout
        return self.layout, None, "custom"

    @property
    def movers(self) -> int:
        """The number of movers per world: ``num_movers``, else the benchmark layout's."""
        if self.num_movers is not None:
            return int(self.num_movers)
        movers = self.resolve_layout()[1]
        if movers is None:
            raise ValueError(f"num_movers must be a positive integer for a custom layout, got {self.num_movers!r}")
        return movers

    def collision_sizes(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The per-mover circle radii ``(M,)`` or box half sizes ``(M, 2)`` (:func:`per_mover_sizes`)."""
        return per_mover_sizes(self.collision_shape, self.collision_size, self.movers)

    def make_mover(self) -> MoverSpec:
        """The mover the simulator is built with: the body of ``mover_params``, the collision shape at its largest
        per-mover size, ``safety_margin`` and the wall margin."""
        radii, halves = self.collision_sizes()
        largest = radii.max() if radii is not None else halves.max(axis=0) if halves is not None else None
        return make_mover_spec(self.collision_shape, largest, wall_margin=self.collision_offset_wall,
                               mover_params=self.mover_params, margin=self.safety_margin)

    def sensor_config(self) -> Any:
        """``sensors``, or MagBotSim's ``std_noise`` as a :class:`~magwarp.envs.sim2real.SensorConfig`."""
        if self.sensors is not None:
            return self.sensors
        return SensorConfig(pos_noise_std=float(self.std_noise), vel_noise_std=float(self.std_noise))
