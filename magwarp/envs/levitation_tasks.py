"""The tasks of the levitation env (:mod:`magwarp.envs.levitation`): start poses, references, extra observations,
when tracking counts and what a task adds to the simulator (a payload, a swinging bob).

Every task holds its per-world terms on the device; the env calls :meth:`Task.episode` for the worlds it resets
(after drawing their start x/y and yaw), :meth:`Task.advance` after every step (the reference at the step's end)
and :meth:`Task.observe` for its extra observation columns. Options are frozen dataclasses (``task_options=``, or a
dict of their fields: ``--env-kwargs '{"task_options": {"time": 0.3}}'``), checked when built.

* ``hover``: the start pose. ``setpoint``: a fixed pose near the start (the env's ``setpoint_*`` options).
* ``liftoff`` (:class:`LiftoffOptions`): the mover starts resting at the lowest gap (``start_gap``, the bottom of the
  default wrench table) on a support that it cannot sink through (``support=False``: released there, it drops out of
  ``fail_gap`` within about 15 ms unless lifted) and must rise to a hover pose at ``setpoint_gap`` above the same x/y
  and yaw.
* ``track`` (:class:`TrackOptions`): a moving 6-DoF reference: per world and axis, ``r(t) = r0 + A (sin(2 pi f t +
  phi) - sin(phi))`` from the start pose (x, y, z about the middle of ``setpoint_gap``, roll, pitch, yaw), amplitudes
  ``A`` uniform up to the options' (z: a quarter of ``setpoint_gap``'s span), ``f`` uniform in ``frequency``, ``phi``
  uniform. Extra observations: the reference's roll and pitch, its velocity and acceleration (6 + 6: linear, then
  roll, pitch, yaw rates).
* ``move`` (:class:`MoveOptions`): an energy-optimal point-to-point move: a goal ``distance`` away (x/y, through the
  layout's centre) and up to ``yaw`` turned, to be reached by ``time`` (s); the pose error counts in the reward only
  from then on, the copper loss always. Extra observation: the time left (s, 0 after the deadline). Success: within
  ``success_tol`` at the episode's end; the metric is the copper energy per move.
* ``payload`` (:class:`PayloadOptions`): hover holding a rigid payload that shifts the centre of mass: per episode a
  point mass uniform in ``mass`` at a body-frame offset (x/y uniform within ``offset``, ``height`` above the centre;
  :attr:`magwarp.sim.Simulator.mover_params`). Extra observations: its mass (kg) and offset (m, 3).
* ``pendulum`` (:class:`PendulumOptions`): hover holding a swinging payload (:mod:`magwarp.pendulum`: a bob of
  ``mass`` on a rod of ``length`` from a ``pivot`` on the mover), started ``angle`` (rad) from hanging straight down
  towards a random direction. Extra observations: the swing angles and their rates (rad, rad/s: x-z and y-z planes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch

__all__ = ["LiftoffOptions", "MoveOptions", "PayloadOptions", "PendulumOptions", "TASKS", "TrackOptions",
           "check_ranges", "make_task", "pair", "wrap"]


def wrap(a: torch.Tensor) -> torch.Tensor:
    return torch.remainder(a + math.pi, 2 * math.pi) - math.pi


def pair(name: str, value, minimum: float = 0.0) -> tuple[float, float]:
    """Two finite numbers ``(low, high)``, ``minimum <= low < high``, or a ValueError naming ``name``."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be two numbers (low, high), got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and minimum <= lo < hi):
        raise ValueError(f"{name} must be two finite numbers with {minimum} <= low < high, got {value!r}")
    return lo, hi


def check_ranges(ranges: dict) -> None:
    """``{name: (value, low, high, low_included)}``: each value a finite number in its range, or a ValueError naming
    it (``high`` is included)."""
    for name, (value, low, high, closed) in ranges.items():
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value <= high
        if not ok or value < low or (value == low and not closed):
            raise ValueError(f"{name} must be a finite number in {'[' if closed else '('}{low}, {high}], got "
                             f"{value!r}")


@dataclass(frozen=True)
class LiftoffOptions:
    """``task="liftoff"``: the gap (m, tile surface to the mover's bottom) the mover starts at, at rest, and whether
    it rests there on a support (``support``: the mover cannot sink below it, :mod:`magwarp.kernels.support`) or is
    released there (it falls unless lifted)."""

    start_gap: float = 0.002
    support: bool = True

    def __post_init__(self):
        check_ranges({"start_gap": (self.start_gap, 0.0, 0.05, False)})
        if not isinstance(self.support, bool):
            raise ValueError(f"support must be True or False, got {self.support!r}")


@dataclass(frozen=True)
class TrackOptions:
    """``task="track"``: largest amplitudes of the moving reference (x/y m, roll/pitch rad, yaw rad) and its
    frequencies (Hz, per axis uniform in ``(low, high)``)."""

    range: float = 0.005
    tilt: float = 0.003
    yaw: float = 0.1
    frequency: tuple[float, float] = (0.2, 1.0)

    def __post_init__(self):
        check_ranges({"range": (self.range, 0.0, 0.1, True), "tilt": (self.tilt, 0.0, 0.02, True),
                      "yaw": (self.yaw, 0.0, math.pi, True)})
        object.__setattr__(self, "frequency", pair("frequency", self.frequency))
        if self.frequency[1] > 50.0:
            raise ValueError(f"frequency must stay at most 50 Hz (a tenth of the default 1 kHz policy), got "
                             f"{self.frequency!r}")


@dataclass(frozen=True)
class MoveOptions:
    """``task="move"``: the goal's distance (m, uniform in ``(low, high)``), its largest yaw turn (rad) and the
    arrival deadline (s from the episode's start)."""

    distance: tuple[float, float] = (0.05, 0.15)
    yaw: float = 0.5
    time: float = 0.5

    def __post_init__(self):
        object.__setattr__(self, "distance", pair("distance", self.distance))
        if self.distance[1] > 1.0:
            raise ValueError(f"distance must be at most 1 m, got {self.distance!r}")
        check_ranges({"yaw": (self.yaw, 0.0, math.pi, True), "time": (self.time, 0.0, 60.0, False)})


@dataclass(frozen=True)
class PayloadOptions:
    """``task="payload"``: payload mass (kg, uniform in ``(low, high)``), largest x/y offset of its centre from the
    mover centre (m, body frame) and its height above the mover centre (m)."""

    mass: tuple[float, float] = (0.05, 0.5)
    offset: float = 0.04
    height: float = 0.03

    def __post_init__(self):
        object.__setattr__(self, "mass", pair("mass", self.mass))
        if self.mass[1] > 5.0:
            raise ValueError(f"mass must be at most 5 kg (the coils lift about 2 kg), got {self.mass!r}")
        check_ranges({"offset": (self.offset, 0.0, 0.1, True), "height": (self.height, -0.1, 0.2, True)})


@dataclass(frozen=True)
class PendulumOptions:
    """``task="pendulum"``: bob mass (kg), rod length (m), pivot (m, body frame from the mover centre) and the start
    angle from hanging straight down (rad, uniform in ``(low, high)``)."""

    mass: float = 0.2
    length: float = 0.08
    pivot: tuple[float, float, float] = (0.0, 0.0, 0.1)
    angle: tuple[float, float] = (0.05, 0.3)

    def __post_init__(self):
        check_ranges({"mass": (self.mass, 0.0, 2.0, True), "length": (self.length, 0.0, 1.0, False)})
        object.__setattr__(self, "angle", pair("angle", self.angle))
        if self.angle[1] > 0.5 * math.pi:
            raise ValueError(f"angle must stay at most pi / 2 (the bob below its pivot), got {self.angle!r}")
        try:
            pivot = tuple(float(v) for v in self.pivot)
        except (TypeError, ValueError):
            pivot = ()
        if len(pivot) != 3 or not all(math.isfinite(v) and abs(v) <= 1.0 for v in pivot):
            raise ValueError(f"pivot must be three finite numbers within 1 m, got {self.pivot!r}")
        object.__setattr__(self, "pivot", pivot)


class Task:
    """A task's terms (see the module docstring); the base class is ``hover``."""

    name = "hover"
    options_type: type | None = None
    #: names and widths of the observation's extra columns (after the 19 common ones)
    extra_obs: tuple[tuple[str, int], ...] = ()

    def __init__(self, env, options=None):
        self.env, self.options = env, options

    def check(self, layout, table_gap: tuple[float, float]) -> None:
        """Refuse options that do not fit the env (its layout, gaps, episode length, the wrench table's gaps)."""

    def sim_kwargs(self) -> dict:
        """What the task needs from the simulator (a force model and its ``force_aux`` width)."""
        return {}

    def setup(self) -> None:
        """After the simulator and the actuator are built."""

    def episode(self, mask: torch.Tensor, xy: torch.Tensor, yaw: torch.Tensor):
        """Start x/y ``[N, 2]`` and gap ``[N]`` (m), reference ``[N, 6]`` (x, y, z, yaw, roll, pitch) and the x/y
        error allowed before failing ``[N]`` for new episodes drawn at ``xy``, ``yaw`` (the env keeps the rows of
        ``mask``; the start is level, at rest, at ``yaw``)."""
        gap = self._hover_gap()
        return xy, gap, self._reference(xy, gap, yaw), self._allow()

    def _hover_gap(self) -> torch.Tensor:
        env = self.env
        return torch.full((env.num_envs,), env.mover.hover_z - env.bottom, device=env.device)

    def _allow(self, extra: torch.Tensor | float = 0.0) -> torch.Tensor:
        env = self.env
        return torch.full((env.num_envs,), env.fail_distance, device=env.device) + extra

    def _reference(self, xy, gap, yaw) -> torch.Tensor:
        """A level reference pose ``[N, 6]`` (x, y, z, yaw, roll, pitch) at ``gap`` above the tiles."""
        zero = torch.zeros_like(yaw)[:, None]
        return torch.cat([xy, (gap + self.env.bottom)[:, None], yaw[:, None], zero, zero], 1)

    def advance(self) -> None:
        """After every step: the reference at the step's end."""

    def tracking_weight(self) -> torch.Tensor | float:
        """``[N]`` or a number: how much the pose error counts in this step's reward."""
        return 1.0

    def observe(self) -> list[torch.Tensor]:
        return []


class SetpointTask(Task):
    name = "setpoint"

    def episode(self, mask, xy, yaw):
        env = self.env
        n = env.num_envs
        d = (2 * env._rand(n, 2) - 1) * env.setpoint_range
        gap = env.setpoint_gap[0] + (env.setpoint_gap[1] - env.setpoint_gap[0]) * env._rand(n)
        dyaw = (2 * env._rand(n) - 1) * env.setpoint_yaw
        return xy, self._hover_gap(), self._reference(xy + d, gap, wrap(yaw + dyaw)), self._allow()


class LiftoffTask(Task):
    name = "liftoff"
    options_type = LiftoffOptions

    def check(self, layout, table_gap):
        g, fail_gap, setpoint_gap = self.options.start_gap, self.env.fail_gap, self.env.setpoint_gap
        if not (fail_gap[0] < g < setpoint_gap[0] and g >= table_gap[0] - 1e-12):
            raise ValueError(f"start_gap {g!r} must lie above fail_gap's low end {fail_gap[0]}, below setpoint_gap "
                             f"{setpoint_gap} and within the wrench table's gaps {table_gap} (its look-ups clamp)")

    def setup(self):
        self.support = None
        if self.options.support:
            from magwarp.support import RestingSupport

            self.support = RestingSupport(self.env.sim, self.options.start_gap + self.env.bottom)

    def episode(self, mask, xy, yaw):
        env = self.env
        n = env.num_envs
        gap = env.setpoint_gap[0] + (env.setpoint_gap[1] - env.setpoint_gap[0]) * env._rand(n)
        start = torch.full((n,), self.options.start_gap, device=env.device)
        return xy, start, self._reference(xy, gap, yaw), self._allow()


class TrackTask(Task):
    name = "track"
    options_type = TrackOptions
    extra_obs = (("reference_tilt", 2), ("reference_vel", 6), ("reference_acc", 6))

    def setup(self):
        env = self.env
        n, dev = env.num_envs, env.device
        self.base = torch.zeros((n, 6), device=dev)  # x, y, z, yaw, roll, pitch (the reference's order)
        self.amp, self.omega, self.phase = (torch.zeros((n, 6), device=dev) for _ in range(3))
        o = self.options
        span = 0.25 * (env.setpoint_gap[1] - env.setpoint_gap[0])
        self.top = torch.tensor([o.range, o.range, span, o.yaw, o.tilt, o.tilt], device=dev)  # largest amplitudes

    def episode(self, mask, xy, yaw):
        env, o = self.env, self.options
        n = env.num_envs
        mid = torch.full((n,), 0.5 * (env.setpoint_gap[0] + env.setpoint_gap[1]), device=env.device)
        base = self._reference(xy, mid, yaw)
        amp = env._rand(n, 6) * self.top
        lo, hi = o.frequency
        omega = 2 * math.pi * (lo + (hi - lo) * env._rand(n, 6))
        phase = 2 * math.pi * env._rand(n, 6)
        keep = mask[:, None]
        for name, new in (("base", base), ("amp", amp), ("omega", omega), ("phase", phase)):
            old = getattr(self, name)
            old.copy_(torch.where(keep, new, old))
        return xy, mid, base, self._allow()

    def advance(self):
        env = self.env
        t = (env.steps.to(torch.float32) * env.step_dt)[:, None]
        arg = self.omega * t + self.phase
        env.reference.copy_(self.base + self.amp * (torch.sin(arg) - torch.sin(self.phase)))
        env.reference_vel.copy_(self.amp * self.omega * torch.cos(arg))
        env.reference_acc.copy_(-self.amp * self.omega * self.omega * torch.sin(arg))

    def observe(self):
        env = self.env
        order = [0, 1, 2, 4, 5, 3]  # linear, then roll, pitch, yaw
        return [env.reference[:, 4:6], env.reference_vel[:, order], env.reference_acc[:, order]]


class MoveTask(Task):
    name = "move"
    options_type = MoveOptions
    extra_obs = (("time_left", 1),)

    def check(self, layout, table_gap):
        layout_half = 0.5 * min(layout.shape) * layout.tile.size
        half_mover = 0.5 * max(self.env.mover.size[:2])
        reach = 0.5 * self.options.distance[1] + self.env.start_range + half_mover
        if reach > layout_half:
            raise ValueError(f"distance {self.options.distance} does not fit the layout: a move through its centre "
                             f"reaches {reach:.3f} m (half the move, start_range and half the mover) from it, beyond "
                             f"the tiles' {layout_half:.3f} m (use more tiles)")
        steps = self.options.time / self.env.step_dt
        if steps >= self.env.max_episode_steps:
            raise ValueError(f"time {self.options.time!r} s must end before the episode does (max_episode_steps "
                             f"{self.env.max_episode_steps} x {self.env.step_dt:g} s)")

    def episode(self, mask, xy, yaw):
        env, o = self.env, self.options
        n = env.num_envs
        dist = o.distance[0] + (o.distance[1] - o.distance[0]) * env._rand(n)
        heading = 2 * math.pi * env._rand(n)
        half = 0.5 * dist[:, None] * torch.stack([torch.cos(heading), torch.sin(heading)], 1)
        dyaw = (2 * env._rand(n) - 1) * o.yaw
        gap = self._hover_gap()
        return xy - half, gap, self._reference(xy + half, gap, wrap(yaw + dyaw)), self._allow(dist)

    def time_left(self) -> torch.Tensor:
        return torch.clamp(self.options.time - self.env.steps.to(torch.float32) * self.env.step_dt, min=0.0)

    def tracking_weight(self):
        return (self.time_left() <= 0).to(torch.float32)

    def observe(self):
        return [self.time_left()[:, None]]


class PayloadTask(Task):
    name = "payload"
    options_type = PayloadOptions
    extra_obs = (("payload_mass", 1), ("payload_offset", 3))

    def setup(self):
        self.params = self.env.sim.mover_params  # per-world body rows (the general step kernels)

    def episode(self, mask, xy, yaw):
        env, o = self.env, self.options
        n = env.num_envs
        mass = o.mass[0] + (o.mass[1] - o.mass[0]) * env._rand(n)
        offset = torch.cat([(2 * env._rand(n, 2) - 1) * o.offset, torch.full((n, 1), o.height, device=env.device)], 1)
        p = self.params
        p["payload"][:, 0].copy_(torch.where(mask, mass.double(), p["payload"][:, 0]))
        p["payload_offset"][:, 0].copy_(torch.where(mask[:, None], offset.double(), p["payload_offset"][:, 0]))
        env.sim.commit_mover_params(mask)
        return super().episode(mask, xy, yaw)

    def observe(self):
        p = self.params
        return [p["payload"][:, 0, None].float(), p["payload_offset"][:, 0].float()]


class PendulumTask(Task):
    name = "pendulum"
    options_type = PendulumOptions
    extra_obs = (("swing_angle", 2), ("swing_rate", 2))

    def sim_kwargs(self):
        from magwarp.pendulum import PENDULUM_AUX_DIM, magnetic_pendulum_force

        return {"force_model": magnetic_pendulum_force, "force_aux_dim": PENDULUM_AUX_DIM}

    def setup(self):
        from magwarp.pendulum import SwingingPayload

        o = self.options
        self.swing = SwingingPayload(self.env.sim, mass=o.mass, length=o.length, pivot=o.pivot)

    def episode(self, mask, xy, yaw):
        env, o = self.env, self.options
        n = env.num_envs
        angle = o.angle[0] + (o.angle[1] - o.angle[0]) * env._rand(n)
        self.swing.reset(mask, angle, 2 * math.pi * env._rand(n))
        return super().episode(mask, xy, yaw)

    def observe(self):
        angles, rates = self.swing.swing()
        return [angles[:, 0], rates[:, 0]]


TASKS = {cls.name: cls for cls in (Task, SetpointTask, LiftoffTask, TrackTask, MoveTask, PayloadTask, PendulumTask)}


def make_task(env, task: str, options) -> Task:
    """The task ``task`` of ``env`` with ``options`` (its options dataclass, a dict of its fields, or None)."""
    if task not in TASKS:
        raise ValueError(f"task must be one of {', '.join(repr(t) for t in TASKS)}, got {task!r}")
    cls = TASKS[task]
    kind = cls.options_type
    if kind is None:
        if options:
            raise ValueError(f"task {task!r} takes no task_options, got {options!r}")
        return cls(env)
    if options is None:
        options = kind()
    elif isinstance(options, dict):
        known = {f.name for f in fields(kind)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ValueError(f"task_options for task {task!r}: unknown option(s) {unknown}; known: {sorted(known)}")
        options = kind(**options)
    elif not isinstance(options, kind):
        raise TypeError(f"task_options for task {task!r} must be a {kind.__name__} or a dict of its fields, got "
                        f"{type(options).__name__}")
    return cls(env, options)
