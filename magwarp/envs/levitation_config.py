"""The options of :class:`~magwarp.envs.levitation.LevitationEnv` as one typed, frozen dataclass
(:mod:`magwarp.envs.config`): every option is checked here, before the magnetic model or the simulator is built."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from magwarp._checks import as_count
from magwarp.envs.levitation_tasks import TASKS, check_ranges, pair

__all__ = ["LevitationConfig"]


def _tolerance(value) -> tuple[float, float]:
    """``success_tol``: two positive finite numbers (m, rad)."""
    try:
        pos, rot = (float(v) for v in value)
    except (TypeError, ValueError):
        pos = rot = float("nan")
    if not all(math.isfinite(v) and 0 < v <= 1.0 for v in (pos, rot)):
        raise ValueError(f"success_tol must be two numbers in (0, 1] (m, rad), got {value!r}")
    return pos, rot


def _scales(value) -> tuple[float, float]:
    """``wrench_scale``: two numbers in (0, 1e6] (N, N m)."""
    try:
        scales = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        scales = ()
    if len(scales) != 2 or not all(math.isfinite(v) and 0 < v <= 1e6 for v in scales):
        raise ValueError(f"wrench_scale must be two numbers in (0, 1e6] (N, N m), got {value!r}")
    return scales


def _tiles(value) -> tuple[int, int]:
    try:
        tiles = tuple(as_count(t, "tiles") for t in value)
    except TypeError:
        raise TypeError(f"tiles must be two positive integers (nx, ny), got {value!r}") from None
    if len(tiles) != 2:
        raise ValueError(f"tiles must be two positive integers (nx, ny), got {value!r}")
    return tiles


@dataclass(frozen=True)
class LevitationConfig:
    """Options of :class:`~magwarp.envs.levitation.LevitationEnv` (the module docstring there says what each does).

    * ``task`` (``"hover"``, ``"setpoint"``, ``"liftoff"``, ``"track"``, ``"move"``, ``"payload"``, ``"pendulum"``)
      and ``task_options`` (its options dataclass or a dict of its fields; checked when the env builds the task);
      ``action``: ``"currents"`` (coil current shares) or ``"wrench"`` (a wrench the commutation turns into currents,
      in shares of ``wrench_scale`` (N, N m)).
    * The plant: ``tiles`` (nx, ny), ``dt`` (s, the control cycle), ``num_cycles`` per env step,
      ``max_episode_steps``; ``magnetics``: a :class:`~magwarp.magnetics.drive.MagneticModel` (None: the default
      design, its table covering 2-6 mm gaps).
    * Starts and setpoints: ``start_range`` (m), ``setpoint_range`` (m), ``setpoint_gap`` (m, low and high),
      ``setpoint_yaw`` (rad).
    * Reward: ``pos_scale`` (m), ``rot_scale`` (rad), ``loss_weight`` (per W), ``failure_reward``.
    * Ends and success: ``fail_gap`` (m, low and high, around ``setpoint_gap``), ``fail_tilt`` (rad),
      ``fail_distance`` (m), ``success_tol`` (m, rad).

    A bad value raises naming it, in ``__post_init__``; pairs are stored as tuples of floats."""

    task: str = "setpoint"
    task_options: Any = None
    action: str = "currents"
    tiles: tuple[int, int] = (2, 2)
    dt: float = 2.5e-4
    num_cycles: int = 4
    max_episode_steps: int = 500
    start_range: float = 0.03
    setpoint_range: float = 0.01
    setpoint_gap: tuple[float, float] = (0.003, 0.005)
    setpoint_yaw: float = 0.1
    pos_scale: float = 0.01
    rot_scale: float = 0.1
    loss_weight: float = 1e-3
    failure_reward: float = -100.0
    fail_gap: tuple[float, float] = (0.001, 0.007)
    fail_tilt: float = 0.05
    fail_distance: float = 0.05
    success_tol: tuple[float, float] = (1e-3, 0.01)
    wrench_scale: tuple[float, float] = (40.0, 2.0)
    magnetics: Any = None

    def __post_init__(self):
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731 - the frozen fields' normal form
        if self.action not in ("currents", "wrench"):
            raise ValueError(f"action must be 'currents' or 'wrench', got {self.action!r}")
        if not isinstance(self.task, str) or self.task not in TASKS:
            raise ValueError(f"task must be one of {', '.join(repr(t) for t in TASKS)}, got {self.task!r}")
        # (low, high, low included): what keeps every reward, observation and pose finite and an episode possible
        check_ranges({"dt": (self.dt, 0.0, 0.01, False), "pos_scale": (self.pos_scale, 1e-6, 1e3, True),
                      "rot_scale": (self.rot_scale, 1e-6, 1e3, True),
                      "fail_tilt": (self.fail_tilt, 0.0, math.pi, False),
                      "fail_distance": (self.fail_distance, 0.0, 1.0, False),
                      "start_range": (self.start_range, 0.0, 1.0, True),
                      "setpoint_range": (self.setpoint_range, 0.0, 1.0, True),
                      "setpoint_yaw": (self.setpoint_yaw, 0.0, math.pi, True),
                      "loss_weight": (self.loss_weight, 0.0, 1e3, True),
                      "failure_reward": (self.failure_reward, -1e6, 1e6, True)})
        setpoint_gap, fail_gap = pair("setpoint_gap", self.setpoint_gap), pair("fail_gap", self.fail_gap)
        if not fail_gap[0] < setpoint_gap[0] <= setpoint_gap[1] < fail_gap[1] <= 0.05:
            raise ValueError(f"setpoint_gap {setpoint_gap} must lie inside fail_gap {fail_gap}, which must end at "
                             f"most 0.05 m above the tiles")
        put("setpoint_gap", setpoint_gap)
        put("fail_gap", fail_gap)
        put("success_tol", _tolerance(self.success_tol))
        put("wrench_scale", _scales(self.wrench_scale))
        put("tiles", _tiles(self.tiles))
        put("num_cycles", as_count(self.num_cycles, "num_cycles"))
        put("max_episode_steps", as_count(self.max_episode_steps, "max_episode_steps"))
        put("dt", float(self.dt))
        if self.magnetics is not None:
            from magwarp.magnetics.drive import MagneticModel  # (the magnetics package only when one is given)

            if not isinstance(self.magnetics, MagneticModel):
                raise TypeError(f"magnetics must be a MagneticModel, got {type(self.magnetics).__name__}")

    def make_magnetics(self):
        """``magnetics``, or the default design's :class:`~magwarp.magnetics.drive.MagneticModel`."""
        from magwarp.magnetics.drive import MagneticModel

        return self.magnetics if self.magnetics is not None else MagneticModel()
