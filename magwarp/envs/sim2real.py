"""Actuation and sensing models for sim2real (the trajectory-planning env's ``actuation=`` and ``sensors=`` options).

* :class:`ActuationConfig`: **action latency**. With a delay of ``k`` control cycles (1 ms each) the action given to
  ``env.step`` at step ``t`` takes effect ``k`` cycles after the step starts; during the step's first ``k`` cycles
  the previous step's action still acts (zero after a reset). The delay is per world: one value for all, one per
  world, or drawn uniformly from an integer range at every reset of a world (counter-based, below). It runs inside
  the simulator's step kernels (:meth:`magwarp.sim.Simulator.set_latency`): exact to the cycle, no host sync, one
  graph per step. ``0 <= k <= num_cycles``: a longer delay would act after the next action is issued (it would need a
  queue of actions) and is refused.
* **Zero-order hold at the PLC's rate**: this is what ``num_cycles`` already is. An env step holds the action for
  ``num_cycles`` cycles of 1 ms, i.e. the policy runs on a PLC task of period ``num_cycles`` ms and XPlanar's setpoint
  is held between its calls. A hold of ``P`` cycles inside an env step of ``k * P`` cycles is the same as an env step
  of ``P`` cycles with the action repeated ``k`` times, so there is no separate knob.
* :class:`SensorConfig`: **sensor models** on the mover positions (``achieved_goal``) and velocities (the first
  ``2 * num_movers`` entries of ``observation``): a per-world constant bias (per mover and axis, drawn at every reset
  of a world from a Gaussian of mean ``pos_bias``/``vel_bias`` and std ``pos_bias_std``/``vel_bias_std``: std 0 sets
  it), white Gaussian noise drawn every reading (``pos_noise_std``, ``vel_noise_std``), and dropped readings: with
  probability ``dropout_prob`` per world per step, the env returns that world's previous ``observation`` and
  ``achieved_goal`` again (whole entries, the accelerations of ``learn_jerk`` included; ``desired_goal`` is the env's
  own goal, never dropped). The first reading of an episode is never dropped. Rewards, goal checks and metrics see
  what the policy sees (as with MagBotSim's noise). The env's ``std_noise`` is ``SensorConfig(pos_noise_std=s,
  vel_noise_std=s)``, with the same draws for the same seed.

Everything runs on the env's device with no host sync. The models' draws (a latency range of more than one value, a
bias std, noise, a dropout probability) are counter-based (:mod:`magwarp.kernels.sensor_draws`): each value is a pure
function of a key that follows the env's seed (:func:`draw_key`; ``reset(seed=...)`` sets it), a clock
(:class:`DrawClock`: the env steps since the last reseed, or the number of ``reset()`` calls outside a step), the
world, what is drawn and the mover. The kernels that use a draw compute it (the trajectory env's fused step draws no
numbers of its own for these models: no launch), and the torch step fills the same values with small Warp kernels, so
both paths give the same bits. The models never touch the env's torch generator: an env's goals and starts are the
same for a seed with or without them. Since #24 a seed gives other sensor noise, biases, dropped readings and delays
than before (``std_noise`` included: a reading outside a step, too, is a counter-based draw now).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np
import torch
import warp as wp

from magwarp._checks import as_count, check_finite, check_magnitude
from magwarp.kernels import sensor_draws as kdraw

__all__ = ["ActuationConfig", "BackendLatency", "DrawClock", "PushSim2Real", "SensorConfig", "Latency", "SensorModel",
           "as_config", "draw_key"]


def as_config(cls, value, name: str):
    """``value`` as a ``cls`` dataclass: an instance, a dict of its fields (JSON env kwargs, e.g.
    ``--env-kwargs '{"actuation": {"latency_range": [0, 5]}}'``) or None (the defaults: no model)."""
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, dict):
        known = {f.name for f in fields(cls)}
        unknown = sorted(str(k) for k in value if k not in known)
        if unknown:
            raise ValueError(f"{name} has unknown option(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")
        if isinstance(value.get("latency_range"), list):
            value = {**value, "latency_range": tuple(value["latency_range"])}
        return cls(**value)
    raise TypeError(f"{name} must be a {cls.__name__}, a dict of its fields or None, got {value!r}")


@dataclass(frozen=True)
class ActuationConfig:
    """Action latency (see the module docstring). ``latency_cycles``: one delay (control cycles) for every world, or
    one per world (a sequence of ``num_envs`` integers); ``latency_range``: ``(low, high)`` (inclusive): every reset
    of a world draws its delay uniformly from it (then ``latency_cycles`` must be left at 0). Delays must lie in
    ``[0, num_cycles]``."""

    latency_cycles: int | Sequence[int] = 0
    latency_range: tuple[int, int] | None = None

    def __post_init__(self):
        if np.ndim(self.latency_cycles) == 0:
            as_count(self.latency_cycles, "latency_cycles", minimum=0)
        else:
            for w, value in enumerate(np.asarray(self.latency_cycles, dtype=object).reshape(-1).tolist()):
                as_count(value, f"latency_cycles[{w}]", minimum=0)
        if self.latency_range is not None:
            rng = self.latency_range
            if isinstance(rng, (str, bytes)) or not isinstance(rng, Sequence) or len(rng) != 2:
                raise ValueError(f"latency_range must be (low, high) integers, got {rng!r}")
            low = as_count(rng[0], "latency_range low", minimum=0)
            high = as_count(rng[1], "latency_range high", minimum=0)
            if low > high:
                raise ValueError(f"latency_range must have low <= high, got {rng!r}")
            if np.any(np.asarray(self.latency_cycles) != 0):
                raise ValueError(f"give latency_cycles or latency_range, not both (got latency_cycles="
                                 f"{self.latency_cycles!r} and latency_range={rng!r})")

    @property
    def enabled(self) -> bool:
        """Whether the simulator needs its latency path (a range, even ``(0, 0)``, or a non-zero delay)."""
        return self.latency_range is not None or bool(np.any(np.asarray(self.latency_cycles) != 0))

    def delays(self, num_envs: int, num_cycles: int) -> tuple[np.ndarray, int]:
        """The fixed per-world delays ``[num_envs]`` (the range's low end when drawn) and their bound, checked against
        ``num_envs`` and ``num_cycles`` (errors name the value)."""
        if self.latency_range is not None:
            low, high = (int(v) for v in self.latency_range)
            fixed, bound, what = np.full(num_envs, low), high, f"latency_range={self.latency_range!r}"
        else:
            fixed = np.broadcast_to(np.asarray(self.latency_cycles), (num_envs,)) if np.ndim(
                self.latency_cycles) == 0 else np.asarray(self.latency_cycles).reshape(-1)
            if fixed.shape != (num_envs,):
                raise ValueError(f"latency_cycles must be one integer or {num_envs} (one per env), got "
                                 f"{len(fixed)} values")
            bound, what = int(fixed.max()), f"latency_cycles={self.latency_cycles!r}"
        if bound > num_cycles:
            raise ValueError(f"{what} exceeds num_cycles={num_cycles}: an action must take effect within its own env "
                             f"step (a delay of at most num_cycles cycles)")
        return fixed.astype(np.int64), bound


def _bias_mean(value, name: str) -> torch.Tensor:
    check_finite(**{name: value}, vectors=(name,))
    return torch.as_tensor(np.asarray(value, dtype=np.float32))


@dataclass(frozen=True)
class SensorConfig:
    """Sensor models on mover positions and velocities (see the module docstring). Bias means ``pos_bias`` (m) and
    ``vel_bias`` (m/s): a number, an x/y pair, or anything that broadcasts to ``(num_envs, num_movers, 2)``; stds
    (``*_std``) non-negative; ``dropout_prob`` in ``[0, 1]``."""

    pos_bias: float | Sequence[float] | np.ndarray = 0.0
    pos_bias_std: float = 0.0
    vel_bias: float | Sequence[float] | np.ndarray = 0.0
    vel_bias_std: float = 0.0
    pos_noise_std: float = 0.0
    vel_noise_std: float = 0.0
    dropout_prob: float = 0.0

    def __post_init__(self):
        _bias_mean(self.pos_bias, "pos_bias")
        _bias_mean(self.vel_bias, "vel_bias")
        stds = dict(pos_bias_std=self.pos_bias_std, vel_bias_std=self.vel_bias_std, pos_noise_std=self.pos_noise_std,
                    vel_noise_std=self.vel_noise_std, dropout_prob=self.dropout_prob)
        check_finite(**stds)
        check_magnitude(**stds)
        for name, value in stds.items():
            if value < 0:
                raise ValueError(f"{name} must be >= 0, got {value!r}")
        if self.dropout_prob > 1:
            raise ValueError(f"dropout_prob must be a probability in [0, 1], got {self.dropout_prob!r}")


def check_noise_or_sensors(std_noise: float, sensors) -> None:
    """MagBotSim's ``std_noise`` is ``SensorConfig(pos_noise_std=std_noise, vel_noise_std=std_noise)``: an env's
    options give it or ``sensors``, not both (a ``ValueError`` naming both values)."""
    if sensors is not None and std_noise:
        raise ValueError(f"give std_noise or sensors, not both (got std_noise={std_noise!r}; it is "
                         "SensorConfig(pos_noise_std=std_noise, vel_noise_std=std_noise))")


def draw_key(seed: int) -> int:
    """The int32 key of the sim2real models' draws for an env seed (any non-negative integer; salted apart from the
    randomisation terms' key)."""
    k = (int(seed) ^ (int(seed) >> 32) ^ 0x53E5D0A7) & 0xFFFFFFFF
    return k - (1 << 32) if k >= 1 << 31 else k


class DrawClock:
    """The key and clock of an env's sim2real draws (:mod:`magwarp.kernels.sensor_draws`). :attr:`key`: ``[1]`` int32
    on the device (the fused step's kernels read it there; :meth:`reseed` refills it). :attr:`value`: the clock of the
    draws made now: ``step_count - base`` inside an env step (:meth:`step`), ``-k`` for the ``k``-th ``reset()``
    outside a step since the last reseed (:meth:`tick_reset`). :attr:`epoch` changes with every new clock (a model
    numbers its readings within one)."""

    def __init__(self, seed: int, device):
        self.key = torch.tensor([draw_key(seed)], dtype=torch.int32, device=device)
        self.base = 0  # the env's step count at the last reseed
        self.resets = 0  # reset() calls outside a step since then
        self.value = 0
        self.in_step = False
        self.epoch = 0

    def reseed(self, seed: int, step_count: int) -> None:
        """``reset(seed=...)``: the draws from here on follow ``seed``, as for an env built with it."""
        self.key.fill_(draw_key(seed))
        self.base, self.resets = int(step_count), 0

    @contextlib.contextmanager
    def step(self, step_count: int):
        """The draws inside the ``with`` block are those of the env step after ``step_count`` steps."""
        self.value, self.in_step = int(step_count) - self.base, True
        self.epoch += 1
        try:
            yield
        finally:
            self.in_step = False

    def tick_reset(self) -> None:
        """A reset begins: outside a step it takes the next reset clock (inside one it draws with the step's)."""
        if self.in_step:
            return
        self.resets += 1
        self.value = -self.resets
        self.epoch += 1

    def _launch(self, kernel, dim, slot: int, out, *extra) -> None:
        wp.launch(kernel, dim=dim, device=out.device,
                  inputs=[wp.from_torch(self.key), wp.int64(self.value), int(slot), *extra], outputs=[out])

    def normals(self, slot: int, num_envs: int, num_movers: int) -> torch.Tensor:
        """``[num_envs, num_movers, 2]`` standard normals of ``slot`` at the current clock."""
        z = torch.empty(num_envs, num_movers, 2, device=self.key.device)
        self._launch(kdraw.fill_normals, (num_envs, num_movers), slot, wp.from_torch(z, dtype=wp.vec2))
        return z

    def uniforms(self, slot: int, num_envs: int) -> torch.Tensor:
        """``[num_envs]`` uniforms in ``[0, 1)`` of ``slot`` at the current clock."""
        u = torch.empty(num_envs, device=self.key.device)
        self._launch(kdraw.fill_uniforms, num_envs, slot, wp.from_torch(u))
        return u

    def integers(self, slot: int, low: int, high: int, out: torch.Tensor) -> None:
        """Uniform integers in ``[low, high]`` of ``slot`` at the current clock into ``out`` (``[num_envs]`` int32)."""
        self._launch(kdraw.fill_ints, out.shape[0], slot, wp.from_torch(out), int(low), int(high) - int(low) + 1)


class Latency:
    """Per-world action delays of a simulator, drawn at resets from an :class:`ActuationConfig`'s range (counter-based:
    slot ``DELAY`` of :mod:`magwarp.kernels.sensor_draws`)."""

    def __init__(self, config: ActuationConfig | dict | None, sim, num_cycles: int, clock: DrawClock):
        self.config = config = as_config(ActuationConfig, config, "actuation")
        self.sim = sim
        self.clock = clock
        fixed, bound = config.delays(sim.num_worlds, num_cycles)
        if config.enabled:
            sim.set_latency(fixed, bound=bound)

    @property
    def draw_range(self) -> tuple[int, int] | None:
        """``(low, high)`` of the drawn delays, or None where nothing is drawn (no range, or a single value)."""
        rng = self.config.latency_range
        return None if rng is None or rng[0] == rng[1] else (int(rng[0]), int(rng[1]))

    def reset(self, mask: torch.Tensor) -> None:
        """Draw new delays for the worlds in ``mask`` (with a range of more than one value; fixed delays stay)."""
        rng = self.draw_range
        if rng is None:
            return
        cycles = self.sim.latency_cycles
        draw = torch.empty_like(cycles)
        self.clock.integers(kdraw.DELAY, *rng, draw)
        cycles.copy_(torch.where(mask, draw, cycles))


class SensorModel:
    """Biased, noisy, dropping readings of mover x/y positions and velocities (a :class:`SensorConfig`), on the
    device. The env calls :meth:`reset` for reset worlds, :meth:`new_step` after simulating, :meth:`read` in every
    observation, :meth:`hold` on the observation and :meth:`commit` on what it returned. Its draws are counter-based
    at ``clock``'s value (:mod:`magwarp.kernels.sensor_draws`): the ``r``-th reading of a clock takes slot pair
    ``READ + 2 r`` (velocities, positions), new biases ``BIAS_VEL``/``BIAS_POS``, dropped readings ``DROP``."""

    HELD_KEYS = ("observation", "achieved_goal")

    def __init__(self, config: SensorConfig | dict | None, num_envs: int, num_movers: int, device,
                 clock: DrawClock):
        self.config = config = as_config(SensorConfig, config, "sensors")
        self.clock = clock
        self.num_envs, self.num_movers = int(num_envs), int(num_movers)
        shape = (num_envs, num_movers, 2)
        self.pos_bias = self._bias_tensor(config.pos_bias, config.pos_bias_std, "pos_bias", shape, device)
        self.vel_bias = self._bias_tensor(config.vel_bias, config.vel_bias_std, "vel_bias", shape, device)
        # the bias means on the device (reset draws around them: no host copy inside a step)
        self._mean = {name: torch.as_tensor(np.asarray(mean, dtype=np.float32), device=device)
                      for name, mean in (("pos", config.pos_bias), ("vel", config.vel_bias))}
        # Updated in place (the fused step of the trajectory env reads them through Warp views).
        self._drop = torch.zeros(num_envs, dtype=torch.bool, device=device)
        self._held: dict[str, torch.Tensor] | None = None
        self._reads = (-1, 0)  # (clock epoch, readings drawn in it)

    @staticmethod
    def _bias_tensor(mean, std: float, name: str, shape, device) -> torch.Tensor | None:
        """``[num_envs, num_movers, 2]`` bias (set at resets), or None where there is none (mean 0, std 0)."""
        value = _bias_mean(mean, name)
        try:
            value = torch.broadcast_to(value, shape)
        except RuntimeError:
            raise ValueError(f"{name} must broadcast to (num_envs, num_movers, 2) = {shape}, got shape "
                             f"{tuple(value.shape)}") from None
        if std == 0 and not value.any():  # checked on the host, before the copy to the device
            return None
        return value.to(device).clone()

    def reset(self, mask: torch.Tensor) -> None:
        """New biases for the worlds in ``mask``; their next reading is not dropped."""
        for slot, bias, mean, std in ((kdraw.BIAS_VEL, self.vel_bias, self._mean["vel"], self.config.vel_bias_std),
                                      (kdraw.BIAS_POS, self.pos_bias, self._mean["pos"], self.config.pos_bias_std)):
            if bias is None or std == 0:  # a set bias stays
                continue
            z = self.clock.normals(slot, self.num_envs, self.num_movers)
            bias.copy_(torch.where(mask[:, None, None], mean + std * z, bias))
        self._drop &= ~mask

    def new_step(self) -> None:
        """Draw which worlds drop this step's reading (at the step's clock: :meth:`DrawClock.step`)."""
        p = self.config.dropout_prob
        if p > 0:
            self._drop.copy_(self.clock.uniforms(kdraw.DROP, self.num_envs) < p)

    def _sense(self, slot: int, x: torch.Tensor, bias: torch.Tensor | None, std: float) -> torch.Tensor:
        n = x.shape[0]
        if bias is not None:
            x = x + bias
        x = x.reshape(n, -1)
        if std == 0.0:
            return x
        return x + std * self.clock.normals(slot, self.num_envs, self.num_movers).view(n, -1)

    def read(self, pos_xy: torch.Tensor, vel_xy: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Sensed ``(positions, velocities)``, flattened ``[num_envs, num_movers * 2]``. The ``r``-th reading at the
        clock's value (a step's own reading ``r = 0``, an autoreset's ``r = 1``) draws slots ``READ + 2 r`` and
        ``READ + 2 r + 1``."""
        epoch, r = self._reads
        if epoch != self.clock.epoch:
            epoch, r = self.clock.epoch, 0
        self._reads = (epoch, r + 1)
        vel = self._sense(kdraw.READ + 2 * r, vel_xy, self.vel_bias, self.config.vel_noise_std)
        pos = self._sense(kdraw.READ + 2 * r + 1, pos_xy, self.pos_bias, self.config.pos_noise_std)
        return pos, vel

    def hold(self, obs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """``obs`` with the dropping worlds' :attr:`HELD_KEYS` entries replaced by the ones last returned."""
        if self.config.dropout_prob == 0 or self._held is None:
            return obs
        drop = self._drop[:, None]
        return {k: torch.where(drop, self._held[k], v) if k in self._held else v for k, v in obs.items()}

    def commit(self, obs: dict[str, torch.Tensor]) -> None:
        """Remember what the env returned (the next dropped reading repeats it)."""
        if self.config.dropout_prob == 0:
            return
        if self._held is None:
            self._held = {k: obs[k].clone() for k in self.HELD_KEYS}
        else:  # in place: the buffers stay the same tensors
            for k in self.HELD_KEYS:
                self._held[k].copy_(obs[k])
        self._drop.zero_()


@wp.kernel(enable_backward=False)
def _select_delayed(
    cycle: int,
    # State in:
    delay: wp.array(dtype=wp.int32),
    prev: wp.array3d(dtype=float),
    latest: wp.array3d(dtype=float),
    # State out:
    cmd: wp.array2d(dtype=wp.vec2),
    cmd_c: wp.array2d(dtype=float),
):
    """The command acting from ``cycle`` on: the previous step's during the world's first ``delay[w]`` cycles, then
    the latest one (x/y into ``cmd``; a third component, the yaw command, into ``cmd_c``)."""
    w, m = wp.tid()
    held = cycle < delay[w]
    for k in range(prev.shape[2]):
        v = latest[w, m, k]
        if held:
            v = prev[w, m, k]
        if k < 2:
            c = cmd[w, m]
            c[k] = v
            cmd[w, m] = c
        else:
            cmd_c[w, m] = v


class BackendLatency:
    """Action latency on the mujoco-warp backend (the push envs), with the planar simulator's semantics (see
    :class:`ActuationConfig`): the env hands the step's action to :meth:`set_action` instead of the backend; the
    backend's command buffers then hold the previous action during each world's first ``delay[w]`` cycles and the new
    one after: a tiny kernel after each of the step's first ``bound`` cycles, inside the step graph (a cycle hook of
    :class:`magwarp.physics.MjwBackend`), no host sync. ``delay``: ``[W]`` int32 on the device (drawn at resets from
    a range). Off (no hook, no copies) unless the config asks for a delay."""

    def __init__(self, config: ActuationConfig | dict | None, backend, num_cycles: int, generator: torch.Generator):
        self.config = config = as_config(ActuationConfig, config, "actuation")
        self.backend, self.generator, self.num_cycles = backend, generator, int(num_cycles)
        fixed, self.bound = config.delays(backend.num_worlds, self.num_cycles)
        self.enabled = config.enabled and backend.num_movers > 0
        if not self.enabled:
            return
        dev = backend.torch_device
        width = 3 if backend.control.rotation else 2
        self.delay = torch.as_tensor(fixed, dtype=torch.int32, device=dev)
        self.new = torch.zeros(backend.num_worlds, backend.num_movers, width, device=dev)
        self.prev = torch.zeros_like(self.new)
        self._hooks_run = 0
        w = {k: wp.from_torch(t) for k, t in (("delay", self.delay), ("prev", self.prev), ("latest", self.new))}
        self._arrays = w
        backend.add_cycle_hook(self._after_cycle)

    def _after_cycle(self) -> None:
        """Launched after every cycle of the step graph: before cycle ``c`` (1 .. bound) select its command."""
        c = self._hooks_run % self.num_cycles + 1
        self._hooks_run += 1
        if c > self.bound or c >= self.num_cycles:
            return
        b, a = self.backend, self._arrays
        wp.launch(_select_delayed, dim=(b.num_worlds, b.num_movers), device=b.device,
                  inputs=[c, a["delay"], a["prev"], a["latest"], b.cmd, b.cmd_c])

    def set_action(self, action: torch.Tensor) -> None:
        """The step's action ``[W, M, d]``: kept as the new command; cycle 0's command selected (torch ops)."""
        self.new.copy_(action)
        first = torch.where((self.delay > 0)[:, None, None], self.prev, self.new)
        self.backend.set_actions(first, check_finite=False)

    def end_step(self) -> None:
        """After the step: its action becomes the previous one."""
        self.prev.copy_(self.new)

    def reset(self, mask: torch.Tensor) -> None:
        """Reset worlds start at rest (previous action zero) and draw new delays (with a range)."""
        if not self.enabled:
            return
        self.prev.masked_fill_(mask[:, None, None], 0.0)
        if self.config.latency_range is None:
            return
        low, high = (int(v) for v in self.config.latency_range)
        if low == high:
            return
        draw = torch.randint(low, high + 1, self.delay.shape, generator=self.generator, device=self.delay.device,
                             dtype=self.delay.dtype)
        self.delay.copy_(torch.where(mask, draw, self.delay))


class PushSim2Real:
    """Mixin of the push envs (:class:`magwarp.envs.push.PushEnv`): their ``actuation`` (:class:`BackendLatency`)
    and ``sensors`` (:class:`SensorModel` on the mover x/y positions and velocities of ``observation``; a dropped
    reading repeats the whole ``observation`` and ``achieved_goal``) options, as on the trajectory env. ``sensors``
    replaces ``std_noise`` (not both; its draws are counter-based, :class:`DrawClock`, so the same seed gives other
    noise than ``std_noise``'s, and the env's generator is left to the episodes) and needs the x/y observation layout
    (not ``learn_mover_c_rotation``). The latency's delays are still drawn with the env's generator."""

    latency: BackendLatency | None = None
    sensors: SensorModel | None = None
    draw_clock: DrawClock | None = None

    def _init_sim2real(self, actuation, sensors) -> None:
        self.latency = BackendLatency(actuation, self.backend, self.num_cycles, self._generator)
        if sensors is None:  # (with std_noise or learn_mover_c_rotation refused by the env's PushConfig)
            return
        self.draw_clock = DrawClock(self._generator.initial_seed(), self.device)
        self.sensors = SensorModel(sensors, self.num_envs, self.num_movers, self.device, self.draw_clock)

    def _reseed(self, seed: int) -> None:
        super()._reseed(seed)
        if self.draw_clock is not None:
            self.draw_clock.reseed(seed, self._step_count)

    def _sim2real_reset(self, mask: torch.Tensor) -> None:
        self.latency.reset(mask)
        if self.sensors is not None:
            self.draw_clock.tick_reset()
            self.sensors.reset(mask)

    def _step_backend(self, action: torch.Tensor) -> None:
        """Simulate one env step of ``action`` ``[W, M, d]`` (through the latency model when it is on)."""
        if self.latency.enabled:
            self.latency.set_action(action)
            self.backend.step()
            self.latency.end_step()
        else:
            self.backend.step(action, check_finite=False)
        if self.sensors is not None:
            self.sensors.new_step()

    def _sense_movers(self, xy: torch.Tensor, vel: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Observed mover x/y positions and velocities ``[W, 2 M]`` each (``std_noise`` without a sensor model)."""
        n = xy.shape[0]
        if self.sensors is None:
            return self._noisy(xy, self.std_noise).reshape(n, -1), self._noisy(vel, self.std_noise).reshape(n, -1)
        return self.sensors.read(xy, vel)

    def _hold_obs(self, obs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return obs if self.sensors is None else self.sensors.hold(obs)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = super().reset(seed=seed, options=options)
        if self.sensors is not None:
            self.sensors.commit(obs)
        return obs, info

    def step(self, action):
        if self.sensors is None:
            return super().step(action)
        with self.draw_clock.step(self._step_count):
            out = super().step(action)
        self.sensors.commit(out[0])
        return out
