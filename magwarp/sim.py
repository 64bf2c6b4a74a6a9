"""The batched planar simulator: ``num_worlds`` copies of one layout, each with ``num_movers`` 6-DoF movers.

One call of :meth:`Simulator.step` runs ``num_cycles`` control cycles (control, integration, collision check) for
every world as a single Warp graph replay, on CPU or GPU. State is exposed zero-copy as torch tensors.

Launch shapes (see :mod:`magwarp.kernels.step`): small worlds run *fused*, all cycles in one launch: on CUDA up to
``REGISTER_MAX_MOVERS`` movers one thread per mover, several worlds a block (:mod:`magwarp.kernels.step_blocks`;
``MAGWARP_SMALL_WORLD_KERNEL=registers`` or an actuator: one thread per world), on the CPU one thread per world with
the whole world in registers up to ``REGISTER_MAX_MOVERS`` movers; larger worlds run two or three kernels per cycle,
with a uniform-grid broad phase above 32 movers. Per-cycle hooks (e.g. metrics) force the per-cycle shape so that
they can run between cycles, still inside the same graph. Action latency (:meth:`Simulator.set_latency`, per-world delays of whole cycles) runs inside
the same kernels, compiled in only once it is turned on.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable

import numpy as np
import torch
import warp as wp

from magwarp._checks import as_count, as_finite, check_magnitude, init_warp, stiffness_limit, warp_device
from magwarp._streams import gc_paused, torch_stream
from magwarp.kernels import collision as kcol
from magwarp.kernels import guard as kguard
from magwarp.kernels import options as kernel_options
from magwarp.kernels import params as kparams
from magwarp.kernels import step as kstep
from magwarp.kernels import step_blocks as kblocks
from magwarp.kernels.impedance import default_force
from magwarp.layout import Layout, LayoutError, MoverSpec
from magwarp.types import (COLLIDE_WALL, SHAPE_BOX, SHAPE_CIRCLE, Body, Collision, Grid, Impedance, Limits, Model,
                           Planar64, State)

__all__ = ["Simulator", "default_device"]

# Worlds up to this many movers run the register-resident fused kernel (one specialisation per mover count).
REGISTER_MAX_MOVERS = 8


def default_device() -> str:
    """The first CUDA device when Warp sees one, else the CPU."""
    init_warp()
    return "cuda:0" if wp.is_cuda_available() else "cpu"


def _vec(values, n: int, name: str) -> tuple[float, ...]:
    what = f"{name} must be {n} finite non-negative numbers, got {values!r}"
    arr = _host_array(values, name, what).reshape(-1)
    if arr.size == 1:
        arr = np.repeat(arr, n)
    if arr.size != n or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(what)
    return tuple(float(v) for v in arr)


def _host_array(value, name: str, what: str | None = None) -> np.ndarray:
    """A float64 numpy copy of host or device data (tensors are moved to the host); a TypeError (``what``, or one
    naming ``name``) for anything that is not numbers (strings, ragged or mixed sequences)."""
    what = what or f"{name} must be numbers (an array), got {value!r}"
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    if isinstance(value, (str, bytes)):
        raise TypeError(what)
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise TypeError(what) from None


def _check_finite(name: str, arr: np.ndarray) -> None:
    """Refuse NaN/inf (and values float32 cannot hold), naming the first bad entry."""
    bad = ~np.isfinite(arr) | (np.abs(np.nan_to_num(arr)) > np.finfo(np.float32).max)
    if bad.any():
        idx = [int(i) for i in np.argwhere(bad)[0]]
        raise LayoutError(f"{name} contains a non-finite value at index {idx}: {float(arr[tuple(idx)])!r}")


def _quat_from_rpy(roll, pitch, yaw) -> np.ndarray:
    """Quaternions (x, y, z, w) of intrinsic z-y-x Euler angles (yaw about z, then pitch about y, then roll about x)."""
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    return np.stack([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
                     cr * cp * cy + sr * sp * sy], axis=-1)


class Simulator:
    """Batched mover simulator. See the module docstring; arguments:

    layout: :class:`~magwarp.layout.Layout` or a 0/1 array. num_movers: movers per world (default: one per start
    position given, else required). num_worlds: batch size. mover: :class:`~magwarp.layout.MoverSpec` (mass, size,
    collision shape and margins). start_xy / start_yaw: ``(M, 2)`` / ``(M,)`` shared by all worlds or
    ``(W, M, 2)`` / ``(W, M)`` per world (default: tile centres, yaw 0), hovering and level; or start_pose: full
    6-DoF start poses ``(M, 6)`` / ``(W, M, 6)``, x, y, z, roll, pitch, yaw (see :meth:`set_start_poses`).
    validate_starts: refuse start poses that are off the tiles or in a mover-mover collision (a ``LayoutError``
    naming the movers and poses); pass False to build a simulator for colliding poses on purpose.
    collision_radii ``(M,)`` / collision_half_sizes ``(M, 2)``: per-mover collision sizes. control:
    ``"acceleration"`` or ``"jerk"``. stiffness_lin / stiffness_rot: impedance stiffness; hold_mask: 6 flags (x, y,
    z, roll, pitch, yaw) the impedance controller holds. stop_on_collision: a world stops moving for the rest of a
    step after a collision (MagBotSim's behaviour). force_model: a ``@wp.func`` with
    :func:`~magwarp.kernels.impedance.default_force`'s signature, or ``"magnetic"`` / a ``MagneticModel`` (coil
    currents: :mod:`magwarp.magnetics.drive`, :attr:`magnetic_drive`); force_aux_dim: width of its free per-mover input
    row ``force_aux``. device: ``"cpu"``, ``"cuda:N"`` or None for the best one. fused_max_movers: worlds up to this
    size run fused. max_pairs: room per world in ``pair_list`` (the list of colliding pairs; ``world_pairs`` always
    counts all of them). check_inputs: validate commands (costs a device sync per command; turn off in tight loops
    that produce commands on the device). nan_guard: flag, inside the step graph, every world whose state turns
    non-finite (:attr:`nonfinite_step`, :meth:`nonfinite_worlds`, :meth:`dump_state`); on by default (two small
    launches per step, no host sync; one where the step's motion checks its own movers, as the swarm env's fused
    step does).

    Physical limits are checked at construction: the held impedance axes must be stable at ``dt`` (the semi-implicit,
    critically damped law diverges above ``K = M (0.828 / dt)^2``, :func:`magwarp._checks.stiffness_limit`).
    """

    def __init__(
        self,
        layout: Layout | np.ndarray,
        num_movers: int | None = None,
        num_worlds: int = 1,
        *,
        mover: MoverSpec | None = None,
        start_xy=None,
        start_yaw=None,
        start_pose=None,
        collision_radii=None,
        collision_half_sizes=None,
        dt: float = 0.001,
        v_max: float = 2.0,
        a_max: float = 10.0,
        j_max: float = 100.0,
        control: str = "acceleration",
        stiffness_lin=(1.0, 1.0, 100.0),
        stiffness_rot=(0.1, 0.1, 1.0),
        hold_mask=(0, 0, 1, 1, 1, 1),
        gravity: float = 9.81,
        stop_on_collision: bool = True,
        force_model=None,
        force_aux_dim: int = 1,
        device: str | None = None,
        fused_max_movers: int = 16,
        max_pairs: int = 256,
        use_graph: bool = True,
        check_inputs: bool = True,
        validate_starts: bool = True,
        nan_guard: bool = True,
    ):
        self.layout = layout if isinstance(layout, Layout) else Layout(layout)
        if mover is not None and not isinstance(mover, MoverSpec):
            raise TypeError(f"mover must be a MoverSpec, got {type(mover).__name__}")
        self.mover = mover or MoverSpec()
        num_worlds, num_movers, gravity, hold = self._check_options(num_worlds, num_movers, control, dt, v_max,
                                                                     a_max, j_max, gravity, hold_mask)
        fused_max_movers = as_count(fused_max_movers, "fused_max_movers", minimum=0)
        max_pairs = as_count(max_pairs, "max_pairs")
        from magwarp.magnetics.drive import resolve_force_model  # a name ("magnetic") or a MagneticModel

        force_model, force_aux_dim, attach_drive = resolve_force_model(force_model,
                                                                       as_count(force_aux_dim, "force_aux_dim"))
        self.num_worlds = num_worlds
        self.control = control
        self.check_inputs = check_inputs
        self._init_runtime(device, use_graph)

        start = self._start_arrays(num_movers, start_xy, start_yaw, start_pose)
        self.num_movers = m = start.shape[1]
        self.max_pairs = min(int(max_pairs), max(1, m * (m - 1) // 2))
        radii, half = self._collision_sizes(collision_radii, collision_half_sizes)
        self._fused = m <= fused_max_movers
        self.model = self._build_model(dt, v_max, a_max, j_max, gravity, stiffness_lin, stiffness_rot, hold,
                                       stop_on_collision, radii, half)
        self.state = self._alloc_state(force_aux_dim)
        self._init_step_parts(nan_guard, force_model)
        self._build_kernels()
        self._init_starts(start, validate_starts)
        self.magnetic_drive = attach_drive(self) if attach_drive is not None else None

    # ------------------------------------------------------------------ construction parts
    @staticmethod
    def _check_options(num_worlds, num_movers, control, dt, v_max, a_max, j_max, gravity, hold_mask):
        """The scalar options checked (each error names the bad value): ``(num_worlds, num_movers, gravity, hold)``
        as the constructor uses them."""
        num_worlds = as_count(num_worlds, "num_worlds")
        if num_movers is not None:
            num_movers = as_count(num_movers, "num_movers")
        if control not in ("acceleration", "jerk"):
            raise ValueError(f"control must be 'acceleration' or 'jerk', got {control!r}")
        for name, value in (("dt", dt), ("v_max", v_max), ("a_max", a_max), ("j_max", j_max)):
            if as_finite(value, name) <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        if float(dt) < 1e-6:  # the limits and the stiffness bound divide by dt (squared)
            raise ValueError(f"dt must be at least 1e-6 s (one microsecond; the real cycle is 1e-3 s), got {dt!r}")
        gravity = as_finite(gravity, "gravity")
        check_magnitude(v_max=v_max, a_max=a_max, j_max=j_max, gravity=gravity)
        hold_what = f"hold_mask must be six 0/1 flags (x, y, z, roll, pitch, yaw), got {hold_mask!r}"
        hold = _host_array(hold_mask, "hold_mask", hold_what).reshape(-1)
        if hold.shape != (6,) or not np.all(np.isin(hold, (0, 1))):
            raise ValueError(hold_what)
        return num_worlds, num_movers, gravity, hold

    def _init_runtime(self, device, use_graph: bool) -> None:
        """The device, its stream, the step graphs and the hook lists (empty)."""
        self.device = warp_device(device)
        self._use_graph = use_graph
        self._hooks: list[Callable[[Simulator], None]] = []
        self._pre_hooks: list[Callable[[Simulator], None]] = []
        self._step_callbacks: list[Callable[[], None]] = []
        self._motion: Callable[[Simulator, int], bool] | None = None
        self._graphs: dict[int, wp.Graph] = {}
        # On CUDA, Warp launches on torch's current stream so that kernels and torch ops on the state are ordered
        # without any host synchronisation.
        self._stream = torch_stream(self.torch_device) if self.device.is_cuda else None

    def _init_step_parts(self, nan_guard: bool, force_model) -> None:
        """What the step kernels take beside the model and state: the NaN guard's counter and record, the force
        model, the in-step actuator (none), the nominal body rows and the action latency's placeholders (off)."""
        self.nan_guard = bool(nan_guard)
        # NaN guard: a device step counter and, per world, the step at which its state first held a NaN/inf (-1: none).
        self._steps = wp.zeros(1, dtype=wp.int32, device=self.device)
        self._nonfinite = wp.full(self.num_worlds, -1, dtype=wp.int32, device=self.device)
        self._force_model = force_model or default_force
        # An actuator inside the step kernels (set_actuator: the magnetic drive's commutation); none until set.
        self._actuator: kstep.Actuator | None = None
        self._act_params = kstep.NoActuator()
        self._mover_params: dict[str, torch.Tensor] | None = None  # built by mover_params on first use
        # the body rows as built until make_per_world('body'): the step kernels' nominal variant
        self._nominal_body = True
        # Action latency (set_latency): off until asked for; the kernels then take these placeholders.
        self._latency_bound: int | None = None
        self._prev_cmd = wp.zeros((1, 1), dtype=wp.vec2, device=self.device)
        self._delay = wp.zeros(1, dtype=wp.int32, device=self.device)

    def _init_starts(self, start: np.ndarray, validate: bool) -> None:
        """The start poses on the device (resets are a kernel, not a host round trip), then the first reset; with
        ``validate``, start poses off the tiles or in collision are an error."""
        m = self.num_movers
        self._init_pos = wp.zeros((self.num_worlds, m), dtype=wp.vec3, device=self.device)
        self._init_quat = wp.zeros((self.num_worlds, m), dtype=wp.quat, device=self.device)
        self._reset_mask = wp.zeros(self.num_worlds, dtype=wp.int32, device=self.device)
        self._write_start_poses(start)
        self.reset()
        if validate:
            self._raise_on_start_collisions()

    # ------------------------------------------------------------------ construction helpers
    def _build_kernels(self) -> None:
        latency = self._latency_bound is not None
        nominal = self._nominal_body  # drive gain 1, no payload, the shared gains and limits
        act = self._actuator
        self._advance_kernel, self._fused_kernel, _ = kstep.make_advance_kernel(self._force_model, latency, nominal,
                                                                                act)
        self._movers_block = self._small_world_block()
        if self.num_movers <= REGISTER_MAX_MOVERS:
            if self._movers_block:
                # Tiny worlds, one thread per mover: several worlds a block, poses exchanged through shared memory.
                self._fused_kernel = kblocks.make_movers_kernel(self._force_model, self.num_movers, latency, nominal,
                                                                self._movers_block, kernel_options.SMALL_WORLD_MAXREG,
                                                                kernel_options.SMALL_WORLD_ROWS)
            else:
                # Tiny worlds (the RL regime): the whole world lives in registers for the whole step.
                self._fused_kernel = kstep.make_register_kernel(self._force_model, self.num_movers, latency, nominal,
                                                                kernel_options.REGISTER_ROWS, act)
        self._movers_kernel = self._fused_kernel if self._movers_block else None
        self._graphs.clear()

    def _small_world_block(self) -> int:
        """Threads per block of the one-thread-per-mover fused kernel (:mod:`magwarp.kernels.step_blocks`) where it
        runs the step, else 0 (the register kernel): asked for (:data:`~magwarp.kernels.options.SMALL_WORLD_KERNEL`),
        worlds of at most ``REGISTER_MAX_MOVERS`` movers, no actuator, on CUDA (on the CPU only with Warp's cooperative
        CPU blocks, ``wp.config.enable_cpu_blocks``: tests)."""
        block = kernel_options.SMALL_WORLD_BLOCK
        if (kernel_options.SMALL_WORLD_KERNEL != "movers" or self.num_movers > REGISTER_MAX_MOVERS
                or self._actuator is not None or block < self.num_movers
                or not (self.device.is_cuda or wp.config.enable_cpu_blocks)):
            return 0
        return block

    def _start_arrays(self, num_movers, start_xy, start_yaw, start_pose=None) -> np.ndarray:
        """Start poses ``(W, M, 6)`` (x, y, z, roll, pitch, yaw) from ``start_pose`` or from ``start_xy`` /
        ``start_yaw`` (z = hover height, level), each shared by all worlds or per world; refuses NaN/inf naming the
        value."""
        if start_pose is not None:
            if start_xy is not None or start_yaw is not None:
                raise ValueError("give either start_pose or start_xy/start_yaw, not both")
            pose = _host_array(start_pose, "start_pose")
            if pose.ndim == 2:
                pose = np.broadcast_to(pose, (self.num_worlds, *pose.shape))
            if pose.ndim != 3 or pose.shape[0] != self.num_worlds or pose.shape[2] != 6:
                raise LayoutError(f"start_pose must have shape (num_movers, 6) or (num_worlds={self.num_worlds}, "
                                  f"num_movers, 6) (x, y, z, roll, pitch, yaw), got {np.shape(start_pose)}")
            _check_finite("start_pose", pose)
            if num_movers is not None and pose.shape[1] != int(num_movers):
                raise LayoutError(f"start_pose has {pose.shape[1]} movers but num_movers={num_movers}")
            return np.ascontiguousarray(pose)
        if start_xy is None:
            if num_movers is None:
                raise ValueError("give num_movers or start_xy (or start_pose)")
            if int(num_movers) < 1:
                raise ValueError(f"num_movers must be >= 1, got {num_movers!r}")
            start_xy = self.layout.default_starts(int(num_movers))
        xy = _host_array(start_xy, "start_xy")
        if xy.ndim == 2:
            xy = np.broadcast_to(xy, (self.num_worlds, *xy.shape))
        if xy.ndim != 3 or xy.shape[0] != self.num_worlds or xy.shape[2] != 2:
            raise LayoutError(f"start_xy must have shape (num_movers, 2) or (num_worlds={self.num_worlds}, num_movers, 2), got {np.shape(start_xy)}")
        _check_finite("start_xy", xy)
        if num_movers is not None and xy.shape[1] != int(num_movers):
            raise LayoutError(f"start_xy has {xy.shape[1]} movers but num_movers={num_movers}")
        yaw = np.zeros(xy.shape[:2]) if start_yaw is None else _host_array(start_yaw, "start_yaw")
        if yaw.ndim == 1 and yaw.shape[0] == xy.shape[1]:  # (M,) shared by all worlds; other shapes fail below
            yaw = np.broadcast_to(yaw, xy.shape[:2])
        if yaw.shape != xy.shape[:2]:
            raise LayoutError(f"start_yaw must be finite with shape ({xy.shape[1]},) or {xy.shape[:2]}, got {np.shape(start_yaw)}")
        _check_finite("start_yaw", yaw)
        pose = np.zeros((*xy.shape[:2], 6))
        pose[..., :2] = xy
        pose[..., 2] = self.mover.hover_z
        pose[..., 5] = yaw
        return pose

    def _collision_sizes(self, radii, half):
        m = self.num_movers
        if radii is not None:
            r = _host_array(radii, "collision_radii").reshape(-1)
            if r.shape != (m,) or not np.all(np.isfinite(r)) or np.any(r <= 0):
                raise ValueError(f"collision_radii must be {m} positive finite numbers, got {radii!r}")
        if half is not None:
            h = _host_array(half, "collision_half_sizes")
            if h.shape != (m, 2) or not np.all(np.isfinite(h)) or np.any(h <= 0):
                raise ValueError(f"collision_half_sizes must have shape ({m}, 2) with positive entries, got shape "
                                 f"{h.shape}")
        self._radii_np = np.full(m, self.mover.collision_radius) if radii is None else r
        self._half_np = np.tile(np.asarray(self.mover.collision_half_size), (m, 1)) if half is None else h
        return self._radii_np, self._half_np

    def _build_model(self, dt, v_max, a_max, j_max, gravity, k_lin, k_rot, hold, stop, radii, half) -> Model:
        m, dev = self.num_movers, self.device
        lim = Limits()
        lim.dt, lim.v_max, lim.a_max, lim.j_max = float(dt), float(v_max), float(a_max), float(j_max)
        lim.dt64, lim.v_max64, lim.a_max64, lim.j_max64 = float(dt), float(v_max), float(a_max), float(j_max)
        lim.jerk_mode = 1 if self.control == "jerk" else 0
        lim.gravity = float(gravity)
        imp = Impedance()
        k_lin, k_rot = _vec(k_lin, 3, "stiffness_lin"), _vec(k_rot, 3, "stiffness_rot")
        self._check_stiffness(k_lin, k_rot, hold, float(dt))
        imp.k_lin = wp.vec3(*k_lin)
        imp.k_rot = wp.vec3(*k_rot)
        imp.mask_lin = wp.vec3(*hold[:3])
        imp.mask_rot = wp.vec3(*hold[3:])
        col = Collision()
        col.shape = SHAPE_CIRCLE if self.mover.collision_shape == "circle" else SHAPE_BOX
        col.margin = float(self.mover.margin)
        col.wall_margin = float(self.mover.wall_margin)
        col.tile_size = float(self.layout.tile.size)
        col.stop_on_collision = 1 if stop else 0
        col.full_rect = 1 if bool(self.layout.tiles.all()) else 0
        col.extent = wp.vec2(*self.layout.extent)
        # Grid cells must span the largest interaction distance so that a 3x3 neighbourhood finds every pair.
        if col.shape == SHAPE_CIRCLE:
            reach = float(np.max(radii)) + col.margin
        else:
            reach = float(np.max(np.hypot(half[:, 0] + col.margin, half[:, 1] + col.margin)))
        grid = Grid()
        grid.cell_size = max(2.0 * reach, 1e-3)
        ext = self.layout.extent
        grid.ncx = max(1, int(np.ceil(ext[0] / grid.cell_size)))
        grid.ncy = max(1, int(np.ceil(ext[1] / grid.cell_size)))
        bodies = np.zeros((1, m), dtype=Body.numpy_dtype())  # one shared row until made per world
        bodies["mass"] = self.mover.mass
        bodies["inv_mass"] = 1.0 / self.mover.mass
        bodies["inertia"] = np.asarray(self.mover.inertia)
        bodies["damp_lin"] = 2.0 * np.sqrt(np.asarray(imp.k_lin) * self.mover.mass)
        bodies["damp_rot"] = 2.0 * np.sqrt(np.asarray(imp.k_rot) * np.asarray(self.mover.inertia))
        bodies["k_lin"] = np.asarray(imp.k_lin)
        bodies["k_rot"] = np.asarray(imp.k_rot)
        bodies["drive_gain"] = 1.0
        bodies["v_max"], bodies["a_max"], bodies["j_max"] = lim.v_max64, lim.a_max64, lim.j_max64
        margins = np.array([[col.margin, col.wall_margin]], np.float32)
        return Model(
            num_worlds=self.num_worlds,
            num_movers=m,
            device=dev,
            limits=lim,
            impedance=imp,
            collision=col,
            grid=grid,
            tiles=wp.array(self.layout.tiles.astype(np.int32), dtype=wp.int32, device=dev),
            body=wp.array(bodies, dtype=Body, device=dev),
            radius=wp.array(radii.astype(np.float32)[None], dtype=float, device=dev),
            half_size=wp.array(half.astype(np.float32)[None], dtype=wp.vec2, device=dev),
            margins=wp.array(margins, dtype=wp.vec2, device=dev),
            hover_z=self.mover.hover_z,
        )

    def _check_stiffness(self, k_lin, k_rot, hold, dt: float) -> None:
        """Refuse a held impedance axis whose stiffness is unstable at the cycle time (names the stable limit)."""
        axes = (("stiffness_lin", "x", self.mover.mass), ("stiffness_lin", "y", self.mover.mass),
                ("stiffness_lin", "z", self.mover.mass), ("stiffness_rot", "roll", self.mover.inertia[0]),
                ("stiffness_rot", "pitch", self.mover.inertia[1]), ("stiffness_rot", "yaw", self.mover.inertia[2]))
        for i, (name, axis, inertia) in enumerate(axes):
            k = (k_lin + k_rot)[i]
            limit = stiffness_limit(inertia, dt)
            if hold[i] and k >= limit:
                unit = "kg" if i < 3 else "kg m^2"
                raise ValueError(f"{name} {axis} = {k:g} is unstable at dt = {dt:g} s for a mover of {inertia:.4g} "
                                 f"{unit}: the stable limit is {limit:.4g} (K < M (0.828 / dt)^2); lower it or "
                                 f"shorten dt")

    def _alloc_state(self, aux_dim: int) -> State:
        shape, dev = (self.num_worlds, self.num_movers), self.device

        def z(dtype, s=shape):
            return wp.zeros(s, dtype=dtype, device=dev)

        st = State(
            pos=z(wp.vec3), quat=z(wp.quat), vel=z(wp.vec3), omega=z(wp.vec3), acc=z(wp.vec2), cmd=z(wp.vec2),
            target_pos=z(wp.vec3), target_quat=z(wp.quat), wall=z(wp.int32), flags=z(wp.int32),
            flags_any=z(wp.int32), partner=z(wp.int32), world_pairs=z(wp.int32, self.num_worlds),
            world_walls=z(wp.int32, self.num_worlds), halted=z(wp.int32, self.num_worlds),
            cycles=z(wp.int32, self.num_worlds), force_aux=z(float, (*shape, int(aux_dim))),
            pair_list=z(wp.vec2i, (self.num_worlds, self.max_pairs)), planar=z(Planar64),
        )
        # Placeholders the integration kernel takes when there is no grid (worlds of up to 32 movers).
        self._no_cells = wp.zeros(1, dtype=wp.int32, device=dev)
        self._no_next = wp.zeros((1, 1), dtype=wp.int32, device=dev)
        if self.num_movers > 32:
            g = self.model.grid
            self._cell_head = wp.zeros(self.num_worlds * g.ncx * g.ncy, dtype=wp.int32, device=dev)
            self._next_in_cell = z(wp.int32)
        return st

    # ------------------------------------------------------------------ torch views
    def _t(self, arr):
        return wp.to_torch(arr)

    @property
    def torch_device(self) -> torch.device:
        return torch.device("cuda", self.device.ordinal) if self.device.is_cuda else torch.device("cpu")

    pos = property(lambda self: self._t(self.state.pos), doc="[W, M, 3] mover centres (m)")
    quat = property(lambda self: self._t(self.state.quat), doc="[W, M, 4] orientations (x, y, z, w)")
    vel = property(lambda self: self._t(self.state.vel), doc="[W, M, 3] linear velocities (m/s)")
    omega = property(lambda self: self._t(self.state.omega), doc="[W, M, 3] angular velocities, world frame (rad/s)")
    acc = property(lambda self: self._t(self.state.acc),
                   doc="[W, M, 2] x/y drive accelerations of the last cycle (state: jerk commands integrate it)")
    cmd = property(lambda self: self._t(self.state.cmd), doc="[W, M, 2] current command buffer")
    flags = property(lambda self: self._t(self.state.flags), doc="[W, M] collision bits of the last cycle")
    flags_any = property(lambda self: self._t(self.state.flags_any), doc="[W, M] collision bits over the last step")
    partner = property(lambda self: self._t(self.state.partner), doc="[W, M] lowest colliding mover index, -1 if none")
    world_pairs = property(lambda self: self._t(self.state.world_pairs), doc="[W] colliding pairs, last cycle")
    pair_list = property(lambda self: self._t(self.state.pair_list),
                         doc="[W, max_pairs, 2] colliding pairs (i < j), last cycle; first min(world_pairs, max_pairs) valid")
    world_walls = property(lambda self: self._t(self.state.world_walls), doc="[W] movers off the tiles, last cycle")
    halted = property(lambda self: self._t(self.state.halted), doc="[W] 1 where the world collided during the step")
    cycles = property(lambda self: self._t(self.state.cycles), doc="[W] cycles integrated during the last step")
    force_aux = property(lambda self: self._t(self.state.force_aux), doc="[W, M, K] free inputs of the force model")

    @property
    def yaw(self) -> torch.Tensor:
        """[W, M] heading of each mover (rad)."""
        q = self.quat
        x, y, z, w = q.unbind(-1)
        return torch.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))

    @property
    def radii(self) -> torch.Tensor:
        """[W, M] collision circle radii (m) per world: a broadcast view of the one shared row until
        :meth:`make_per_world` (domain randomisation) gives every world its own."""
        return self._world_view(self.model.radius)

    @property
    def half_sizes(self) -> torch.Tensor:
        """[W, M, 2] collision box half sizes (m) per world (see :attr:`radii`)."""
        return self._world_view(self.model.half_size)

    @property
    def margins(self) -> torch.Tensor:
        """[W, 2] collision margins per world: (mover-mover safety margin, wall margin) in m (see :attr:`radii`)."""
        return self._world_view(self.model.margins)

    def _world_view(self, arr: wp.array) -> torch.Tensor:
        t = self._t(arr)
        return t if t.shape[0] == self.num_worlds else t.expand(self.num_worlds, *t.shape[1:])

    def make_per_world(self, *names: str) -> None:
        """Give every world its own row of the model arrays ``names`` (``"body"``, ``"radius"``, ``"half_size"``,
        ``"margins"``; default all), copied from the shared one. The model is built with one row shared by all
        worlds (the kernels read row ``w`` of a per-world array, row 0 of a shared one: less memory traffic when
        nothing is randomised); per-world rows can then be rewritten on the device between steps. Drops the recorded
        step graphs (they hold the old arrays). With ``"body"``, the step kernels switch from their nominal variant to
        the general one, which reads each row's drive gain, payload, gains and limits."""
        names = names or ("body", "radius", "half_size", "margins")
        for name in names:
            arr = getattr(self.model, name)
            if arr.shape[0] != self.num_worlds:
                rows = np.repeat(arr.numpy(), self.num_worlds, axis=0)
                setattr(self.model, name, wp.array(rows, dtype=arr.dtype, device=self.device))
                self._graphs.clear()
        if "body" in names and self._nominal_body:
            self._nominal_body = False  # body rows may now differ from the mover as built: the general kernels
            self._build_kernels()

    @property
    def mover_params(self) -> dict[str, torch.Tensor]:
        """Per-world mover parameters, ``[W, M]`` or ``[W, M, 3]`` float64 tensors on the device, which
        :meth:`commit_mover_params` packs into the model's :class:`~magwarp.types.Body` rows: ``mass`` (kg, the
        mover's own), ``inertia`` (its principal moments, kg m^2), ``payload`` (kg, a point mass) at
        ``payload_offset`` (m, body frame from the mover centre), ``payload_known`` (kg, the payload the controller
        is configured for), ``k_lin`` / ``k_rot`` (impedance stiffness), ``v_max`` / ``a_max`` / ``j_max`` (x/y
        limits). Built on first use with the configured values (no payload).

        The controller keeps the configured mass and inertia (``mover.mass``, ``mover.inertia``) plus the payload it
        knows of, ``m_c = mover.mass + payload_known``: its x/y drive force is ``m_c * a``, so a mover of true mass
        ``m`` (payload included) accelerates by ``m_c / m * a`` (a known payload leaves the x/y motion as commanded);
        its impedance damping is ``2 sqrt(K m_c)`` and ``2 sqrt(K I)`` with the configured ``I``; the
        levitation carries the true weight at the mover centre, so a payload off the vertical axis tilts the mover
        against the impedance hold (see :func:`magwarp.kernels.step.make_advance_kernel`)."""
        if self._mover_params is None:
            self.make_per_world("body")
            W, M, dev = self.num_worlds, self.num_movers, self.torch_device
            lim, imp = self.model.limits, self.model.impedance

            def full(value, *shape):
                return torch.tensor(value, dtype=torch.float64, device=dev).expand(W, M, *shape).clone()

            p = self._mover_params = {
                "mass": full(self.mover.mass), "inertia": full(list(self.mover.inertia), 3), "payload": full(0.0),
                "payload_offset": full([0.0] * 3, 3), "payload_known": full(0.0), "k_lin": full(list(imp.k_lin), 3),
                "k_rot": full(list(imp.k_rot), 3), "v_max": full(lim.v_max64), "a_max": full(lim.a_max64),
                "j_max": full(lim.j_max64),
            }
            self._pack_mask = torch.ones(W, dtype=torch.bool, device=dev)
            vec = ("inertia", "payload_offset", "k_lin", "k_rot")
            arrays = {k: wp.from_torch(t, dtype=wp.vec3d if k in vec else wp.float64) for k, t in p.items()}
            params = kparams.MoverParams()
            params.m_ctrl = float(self.mover.mass)
            params.i_ctrl = wp.vec3d(*[float(v) for v in self.mover.inertia])
            params.scale_inertia = 0
            for key, name in (("mass", "mass"), ("inertia", "inertia"), ("payload", "payload"),
                              ("payload_offset", "offset"), ("payload_known", "known"), ("k_lin", "k_lin"),
                              ("k_rot", "k_rot"), ("v_max", "v_max"), ("a_max", "a_max"), ("j_max", "j_max")):
                setattr(params, name, arrays[key])
            self._params_struct = params
            self._pack_mask_wp = wp.from_torch(self._pack_mask, dtype=wp.bool)
        return self._mover_params

    def commit_mover_params(self, mask=None, *, scale_inertia: bool = False, current_stream: bool = False) -> None:
        """Pack :attr:`mover_params` into the model's body rows of the worlds in ``mask`` (``[W]`` bool tensor on the
        device; all if None): one kernel launch, no host sync, no rebuild; the next step uses them.
        ``scale_inertia``: use the configured inertia scaled with each mover's mass (uniform density) instead of
        ``mover_params["inertia"]``. Values are not checked here (the randomiser checks its distributions'
        supports): keep masses, inertias and limits positive and the stiffness stable (see the class doc).
        ``current_stream``: launch on Warp's current stream, not the simulator's (inside a captured env step)."""
        self.mover_params  # noqa: B018 - builds the tensors and the launch inputs
        if mask is None:
            self._pack_mask.fill_(True)
        else:
            self._pack_mask.copy_(mask)
        with contextlib.nullcontext() if current_stream else self._on_stream():
            wp.launch(kparams.pack_bodies, dim=(self.num_worlds, self.num_movers), device=self.device,
                      inputs=[self._pack_mask_wp, self.mover_param_struct(scale_inertia), self.model.body])

    def mover_param_struct(self, scale_inertia: bool = False) -> kparams.MoverParams:
        """:attr:`mover_params` as the kernels' :class:`~magwarp.kernels.params.MoverParams` (Warp views of the same
        tensors); ``scale_inertia`` as in :meth:`commit_mover_params`."""
        self.mover_params  # noqa: B018 - builds the tensors and the struct
        self._params_struct.scale_inertia = int(bool(scale_inertia))
        return self._params_struct

    # ------------------------------------------------------------------ inputs
    def _check_tensor(self, name: str, value, shape: tuple[int, ...]) -> torch.Tensor:
        if not isinstance(value, torch.Tensor):
            # Host data (numpy, lists) is copied to the simulator's device; tensors must already be there.
            value = torch.as_tensor(np.asarray(value, dtype=np.float32), device=self.torch_device)
        if not value.is_floating_point():
            raise TypeError(f"{name} must be a floating point tensor, got dtype {value.dtype}")
        if value.device != self.torch_device:
            raise ValueError(f"{name} is on device {value.device}, but the simulator runs on {self.torch_device}")
        if tuple(value.shape) != shape:
            raise ValueError(f"{name} must have shape {shape}, got {tuple(value.shape)}")
        # The state is float32: check what will be stored (a finite float64 such as 1e40 overflows to inf).
        value = value.to(torch.float32)
        if self.check_inputs and not bool(torch.isfinite(value).all()):
            bad = torch.nonzero(~torch.isfinite(value))[0].tolist()
            raise ValueError(f"{name} contains a non-finite value at index {bad}: {value[tuple(bad)].item()}")
        return value

    def set_command(self, cmd) -> None:
        """Write x/y commands ``[W, M, 2]`` (accelerations or jerks); held for the following cycles."""
        value = self._check_tensor("command", cmd, (self.num_worlds, self.num_movers, 2))
        self.cmd.copy_(value)

    def set_latency(self, cycles, *, bound: int | None = None) -> None:
        """Action latency. In world ``w``, a command set before a step (:meth:`set_command`, ``step(cmd=...)``) takes
        effect ``cycles[w]`` control cycles after the step starts: during the step's first ``cycles[w]`` cycles the
        previous step's command still acts (zero after a reset). ``cycles``: one integer for every world, or ``[W]``
        integers (host data, or a tensor on any device: read once on the host to check it, outside any step).
        ``None`` turns latency off again.

        Exact for ``0 <= cycles[w] <= n`` in every later ``step(n)``, which refuses a shorter step (a command delayed
        past the issue of the next one would need a queue of commands). ``bound`` (default: the largest of
        ``cycles``) is the largest delay the worlds will hold: code that redraws the delays on the device (writing
        into :attr:`latency_cycles`, e.g. at resets, with no host round trip) declares its range here.

        Turning latency on builds the step kernels with it compiled in (one compile per kernel) and starts every
        world's previous command at its current one; delays of 0 then step bit for bit as without latency.
        """
        if cycles is None:
            if self._latency_bound is not None:
                self._latency_bound = None
                self._prev_cmd = wp.zeros((1, 1), dtype=wp.vec2, device=self.device)
                self._delay = wp.zeros(1, dtype=wp.int32, device=self.device)
                self._build_kernels()
            return
        delays = self._check_delays(cycles)
        top = int(delays.max())
        if bound is not None:
            bound = as_count(bound, "latency bound", minimum=0)
            if bound < top:
                raise ValueError(f"latency bound must be at least the largest delay given ({top}), got {bound!r}")
        bound = top if bound is None else bound
        if self._latency_bound is None:
            # filled by torch copies below, on torch's stream like every other write into the state
            self._prev_cmd = wp.empty((self.num_worlds, self.num_movers), dtype=wp.vec2, device=self.device)
            self._t(self._prev_cmd).copy_(self.cmd)
            self._delay = wp.empty(self.num_worlds, dtype=wp.int32, device=self.device)
            self._latency_bound = bound
            self._build_kernels()
        self._latency_bound = bound
        self._t(self._delay).copy_(torch.as_tensor(delays, dtype=torch.int32))

    def _check_delays(self, cycles) -> np.ndarray:
        """Latency delays as ``[W]`` int64 on the host; refuses non-integers, negatives and wrong shapes, naming
        them."""
        if isinstance(cycles, torch.Tensor):
            cycles = cycles.detach().cpu().numpy()
        if np.ndim(cycles) == 0:
            return np.full(self.num_worlds, as_count(cycles.item() if isinstance(cycles, np.ndarray) else cycles,
                                                     "latency cycles", minimum=0), dtype=np.int64)
        arr = np.asarray(cycles)
        if arr.shape != (self.num_worlds,):
            raise ValueError(f"latency cycles must be one integer or {self.num_worlds} (one per world), got shape "
                             f"{arr.shape}")
        for w, value in enumerate(arr.tolist()):
            as_count(value, f"latency cycles of world {w}", minimum=0)
        return arr.astype(np.int64)

    @property
    def latency_cycles(self) -> torch.Tensor | None:
        """``[W]`` int32 per-world action delays (cycles) on the device, or None without latency
        (:meth:`set_latency`). Writes into it are not checked: keep them within ``[0, latency_bound]``."""
        return None if self._latency_bound is None else self._t(self._delay)

    @property
    def latency_bound(self) -> int | None:
        """The largest delay the worlds may hold (every step must run at least this many cycles); None: no latency."""
        return self._latency_bound

    @property
    def prev_cmd(self) -> torch.Tensor | None:
        """``[W, M, 2]`` the command acting during a step's delayed cycles (the previous step's), or None without
        latency."""
        return None if self._latency_bound is None else self._t(self._prev_cmd)

    def set_targets(self, yaw=None, z=None) -> None:
        """Set the impedance targets: heading ``[W, M]`` (rad) and/or hover height ``[W, M]`` (m)."""
        shape = (self.num_worlds, self.num_movers)
        tgt_pos = self._t(self.state.target_pos)
        if z is not None:
            tgt_pos[..., 2].copy_(self._check_tensor("z target", z, shape))
        if yaw is not None:
            yaw = self._check_tensor("yaw target", yaw, shape)
            q = self._t(self.state.target_quat)
            q.zero_()
            q[..., 2].copy_(torch.sin(0.5 * yaw))
            q[..., 3].copy_(torch.cos(0.5 * yaw))

    def set_start_poses(self, start_xy=None, start_yaw=None, *, start_pose=None) -> None:
        """Replace the start poses used by :meth:`reset`: ``start_xy`` ``(M, 2)`` or ``(W, M, 2)`` with ``start_yaw``
        likewise (hovering, level), or full 6-DoF ``start_pose`` ``(M, 6)`` / ``(W, M, 6)``: x, y, z, roll, pitch,
        yaw (rad; intrinsic z-y-x: yaw, then pitch, then roll). NaN/inf is refused with an error naming the value.

        A reset also sets each mover's impedance targets to its start pose. The poses are checked for collisions
        when the worlds are reset and then by :meth:`check_collisions`, not here."""
        if start_xy is None and start_pose is None:
            raise ValueError("give start_xy (with start_yaw) or start_pose")
        self._write_start_poses(self._start_arrays(self.num_movers, start_xy, start_yaw, start_pose))

    def _write_start_poses(self, pose: np.ndarray) -> None:
        self._init_pos.assign(pose[..., :3].astype(np.float32))
        self._init_quat.assign(_quat_from_rpy(pose[..., 3], pose[..., 4], pose[..., 5]).astype(np.float32))

    @property
    def start_pos(self) -> torch.Tensor:
        """[W, M, 3] start positions used by reset (write into it on the device to change starts without a sync)."""
        return self._t(self._init_pos)

    @property
    def start_quat(self) -> torch.Tensor:
        return self._t(self._init_quat)

    # ------------------------------------------------------------------ stepping
    def reset(self, mask=None) -> None:
        """Reset the worlds where ``mask`` ([W] bool/int tensor) is true, or all worlds; others are untouched."""
        if mask is None:
            self._t(self._reset_mask).fill_(1)
        else:
            if not isinstance(mask, torch.Tensor):
                mask = torch.as_tensor(np.asarray(mask))
            if mask.shape != (self.num_worlds,):
                raise ValueError(f"reset mask must have shape ({self.num_worlds},), got {tuple(mask.shape)}")
            if mask.dtype not in (torch.bool, torch.int32, torch.int64, torch.uint8):
                raise TypeError(f"reset mask must be bool or integer, got {mask.dtype}")
            if mask.device != self.torch_device:
                raise ValueError(f"reset mask is on {mask.device}, but the simulator runs on {self.torch_device}")
            self._t(self._reset_mask).copy_(mask.to(torch.int32))
        with self._on_stream():
            self._launch_reset()

    def _launch_reset(self) -> None:
        """Reset the worlds flagged in ``_reset_mask`` (int32 ``[W]``) with kernels only, on the current Warp stream:
        no torch op and no host sync, so that a larger captured step (the fused env step, which writes the mask in
        its own kernel) can include it."""
        s = self.state
        # Reset worlds start over as finite and at rest (no previous command for the action latency).
        wp.launch(kguard.clear_reset_worlds, dim=(self.num_worlds, self.num_movers), device=self.device,
                  inputs=[self._reset_mask, 0 if self._latency_bound is None else 1],
                  outputs=[self._nonfinite, self._prev_cmd])
        wp.launch(
            kstep.reset_worlds, dim=(self.num_worlds, self.num_movers), device=self.device,
            inputs=[self._reset_mask, self._init_pos, self._init_quat, s.pos, s.quat, s.vel, s.omega, s.acc,
                    s.cmd, s.target_pos, s.target_quat, s.flags, s.flags_any, s.partner, s.wall,
                    s.world_pairs, s.world_walls, s.halted, s.cycles],
        )

    def _on_stream(self):
        return wp.ScopedStream(self._stream) if self._stream is not None else contextlib.nullcontext()

    def check_collisions(self) -> None:
        """Recompute the collision outputs (flags, partner, per-world counts) for the current poses, without moving."""
        m, s, dev = self.model, self.state, self.device
        W, M = self.num_worlds, self.num_movers
        with self._on_stream():
            wp.launch(kcol.detect_walls, dim=(W, M), device=dev,
                      inputs=[m.tiles, m.collision, m.radius, m.half_size, m.margins, s.pos, s.quat, s.wall])
            self._detect_pairs()

    def _raise_on_start_collisions(self) -> None:
        """Start poses must be on the tiles and collision free: checked with the simulator's own kernels (O(M))."""
        self.check_collisions()
        flags = self.flags.cpu().numpy()
        if not flags.any():
            self.flags_any.zero_()
            return
        w, k = (int(v) for v in np.argwhere(flags)[0])
        xy = tuple(round(float(v), 4) for v in self.pos[w, k, :2].cpu())
        if flags[w, k] & COLLIDE_WALL:
            raise LayoutError(f"mover {k} (world {w}) starts at {xy}, which is off the tiles or too close to an edge")
        j = int(self.partner[w, k])
        other = tuple(round(float(v), 4) for v in self.pos[w, j, :2].cpu())
        raise LayoutError(f"movers {k} and {j} (world {w}) overlap at their start positions {xy} and {other}")

    # ------------------------------------------------------------------ NaN guard
    @property
    def nonfinite_step(self) -> torch.Tensor:
        """[W] int32: the step (counted from construction, 1-based) at which the world's state first held a NaN or
        an infinity; -1 where it is finite. Reset worlds start over at -1. Filled by the NaN guard (``nan_guard``)."""
        return self._t(self._nonfinite)

    @property
    def steps_taken(self) -> int:
        """Steps simulated since construction, as counted on the device by the NaN guard (reads the device)."""
        return int(self._t(self._steps)[0])

    def nonfinite_worlds(self) -> list[tuple[int, int]]:
        """``[(world, step), ...]`` for every world flagged by the NaN guard (one device-to-host copy)."""
        record = self.nonfinite_step.cpu().numpy()
        return [(int(w), int(record[w])) for w in np.flatnonzero(record >= 0)]

    def state_arrays(self, worlds=None) -> dict[str, np.ndarray]:
        """Host copies of the state (and the NaN guard's record) for ``worlds`` (default: all), for bug reports."""
        idx = np.arange(self.num_worlds) if worlds is None else np.asarray(worlds, dtype=np.int64).reshape(-1)
        out = {name: self._t(arr).cpu().numpy()[idx] for name, arr in vars(self.state).items()
               if isinstance(arr, wp.array) and arr.shape[0] == self.num_worlds}
        out["nonfinite_step"] = self.nonfinite_step.cpu().numpy()[idx]
        if self._latency_bound is not None:
            out["prev_cmd"] = self.prev_cmd.cpu().numpy()[idx]
            out["latency_cycles"] = self.latency_cycles.cpu().numpy()[idx]
        out["world"] = idx
        return out

    def dump_state(self, path: str, worlds=None) -> str:
        """Write the state of ``worlds`` (default: those flagged non-finite, else all) and the model's parameters to
        ``path`` (``.npz``) for a bug report; returns the path."""
        import json

        if worlds is None:
            bad = [w for w, _ in self.nonfinite_worlds()]
            worlds = bad or None
        arrays = self.state_arrays(worlds)
        m = self.model
        params = {
            "num_worlds": self.num_worlds, "num_movers": self.num_movers, "control": self.control,
            "device": str(self.device), "layout": self.layout.tiles.tolist(), "mover": repr(self.mover),
            "limits": {k: getattr(m.limits, k) for k in ("dt", "v_max", "a_max", "j_max", "gravity", "jerk_mode")},
            "stiffness_lin": list(m.impedance.k_lin), "stiffness_rot": list(m.impedance.k_rot),
            "versions": {"warp": wp.__version__, "torch": torch.__version__, "numpy": np.__version__},
        }
        np.savez(path, params=np.array(json.dumps(params, default=float)), **arrays)
        return path if path.endswith(".npz") else f"{path}.npz"

    def add_step_callback(self, callback: Callable[[], None]) -> None:
        """Call ``callback()`` on the host at the start of every :meth:`step`, before its graph runs (e.g. interval
        domain-randomisation events, which only queue device work)."""
        self._step_callbacks.append(callback)

    def set_actuator(self, actuator: "kstep.Actuator", params, force_model=None) -> None:
        """Run ``actuator`` inside the step kernels (every cycle of every mover: the force model's wrench is the
        wanted one, the actuator's the acting one; see :mod:`magwarp.kernels.step`), with its parameters ``params``
        (a struct of ``actuator.params_type``); ``force_model`` (a ``@wp.func``) replaces the force model, the
        default: :func:`~magwarp.kernels.impedance.default_force`. Unlike a cycle hook it keeps the fused kernels (one
        launch per step) and their graphs."""
        if not isinstance(actuator, kstep.Actuator) or not isinstance(params, actuator.params_type.cls):
            raise TypeError(f"set_actuator needs a magwarp.kernels.step.Actuator and a params struct of its "
                            f"params_type, got {type(actuator).__name__} and {type(params).__name__}")
        self._actuator, self._act_params = actuator, params
        self._force_model = force_model or default_force
        self._build_kernels()

    def add_cycle_hook(self, hook: Callable[["Simulator"], None], before: bool = False) -> None:
        """Run ``hook(sim)`` after every cycle (``before=True``: before it, e.g. to prepare ``force_aux`` from the
        cycle's starting state), inside the step graph. It must only launch device work."""
        (self._pre_hooks if before else self._hooks).append(hook)
        self._fused = False
        self._graphs.clear()

    def step(self, num_cycles: int = 1, cmd=None) -> None:
        """Advance every world ``num_cycles`` control cycles (optionally setting the command first)."""
        n = as_count(num_cycles, "num_cycles")
        if self._latency_bound is not None and n < self._latency_bound:
            raise ValueError(f"num_cycles={n} is shorter than the action latency's bound of {self._latency_bound} "
                             "cycles (set_latency): a step must last at least as long as its longest delay")
        if cmd is not None:
            self.set_command(cmd)
        for callback in self._step_callbacks:
            callback()
        with self._on_stream():
            if not self._use_graph:
                self._launch_step(n)
                return
            graph = self._graphs.get(n)
            if graph is None:
                # Modules must be loaded before a capture (no compiling inside one): this first, eager step does
                # that, and it is a real step. The capture that follows records without executing. CUDA cannot
                # capture on torch's default (legacy) stream, so capture on a stream of our own and replay on torch's.
                self._launch_step(n)
                self._graphs[n] = self._capture(lambda: self._launch_step(n))
                return
            wp.capture_launch(graph, stream=self._stream)

    def _capture(self, launches) -> wp.Graph:
        """Record ``launches()`` as a graph. CUDA cannot capture on torch's default (legacy) stream, so the capture
        runs on a stream of our own; the graph is replayed on torch's stream."""
        stream = wp.Stream(self.device) if self.device.is_cuda else None
        with gc_paused(stream is not None), wp.ScopedStream(stream) if stream is not None else contextlib.nullcontext():
            with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                launches()
        return capture.graph

    def _block_dim(self, threads: int) -> int:
        """Threads per block on a GPU: small enough that a modest launch still spreads over every SM (the
        fused kernel's threads are long and latency bound), 256 once there is plenty of work."""
        if not self.device.is_cuda:
            return 256
        if os.environ.get("MAGWARP_BLOCK_DIM"):  # fixed override, for tuning
            return int(os.environ["MAGWARP_BLOCK_DIM"])
        per_sm = max(1, threads // (4 * self.device.sm_count))
        return int(min(256, max(32, 1 << (per_sm.bit_length() - 1))))

    def _launch_step(self, n: int) -> None:
        # the NaN guard: the step's number first (the record below, or a motion that checks its own movers, reads it)
        if self.nan_guard:
            wp.launch(kguard.count_step, dim=1, inputs=[self._steps], device=self.device)
        checked = self._launch_motion(n)
        if self.nan_guard and not checked:
            s = self.state
            wp.launch(kguard.flag_nonfinite, dim=(self.num_worlds, self.num_movers), device=self.device,
                      inputs=[self._steps, s.pos, s.quat, s.vel, s.omega, self._nonfinite])

    def set_motion(self, motion: Callable[["Simulator", int], bool] | None) -> None:
        """Let ``motion(sim, n)`` launch the motion of a whole step of ``n`` cycles in place of the built-in kernels
        (e.g. the swarm env's fused step, :mod:`magwarp.swarm.fused`): it returns True where it did, False to let the
        built-in launch shapes run. It runs inside the step graph, before the NaN guard's record, on the simulator's
        stream, and must only launch device work. A motion whose attribute ``checks_nonfinite`` is true also writes
        the NaN guard's record where it ran (with :attr:`nan_guard` on: each world whose record ``sim._nonfinite`` is
        still -1 and one of whose movers' pose or velocity is non-finite after the step gets ``sim._steps[0]``, the
        step's number, already counted), and the separate check over every mover is left out. None: the built-in
        kernels only."""
        if motion is not None and not callable(motion):
            raise TypeError(f"set_motion needs a callable motion(sim, num_cycles) or None, got {motion!r}")
        self._motion = motion
        self._graphs.clear()

    def _launch_motion(self, n: int) -> bool:
        """The step's motion; True where a motion of :meth:`set_motion` ran and wrote the NaN guard's record."""
        if self._motion is not None and self._motion(self, n):
            return bool(getattr(self._motion, "checks_nonfinite", False))
        m, s, dev = self.model, self.state, self.device
        W, M = self.num_worlds, self.num_movers
        if self._fused:  # the fused kernels clear their per-step accumulators themselves
            inputs = [n, m.limits, m.impedance, m.collision, m.tiles, m.body, m.radius, m.half_size, m.margins,
                      self._act_params, s.cmd, self._delay, s.target_pos, s.target_quat, s.force_aux,
                      self._prev_cmd, s.pos, s.quat, s.vel, s.omega, s.acc, s.planar, s.wall, s.flags, s.flags_any,
                      s.partner, s.world_pairs, s.world_walls, s.halted, s.cycles, s.pair_list]
            if self._movers_kernel is not None and self._fused_kernel is self._movers_kernel:
                B = self._movers_block
                wp.launch_tiled(self._fused_kernel, dim=[kblocks.num_blocks(W, M, B)], block_dim=B, device=dev,
                                inputs=inputs)
                return False
            wp.launch(self._fused_kernel, dim=W, device=dev, block_dim=self._block_dim(W), inputs=inputs)
            return False
        wp.launch(kstep.begin_step, dim=(W, M), inputs=[s.flags_any, s.halted, s.cycles], device=dev)
        for c in range(n):
            for hook in self._pre_hooks:
                hook(self)
            self._launch_cycle(c)
            for hook in self._hooks:
                hook(self)
        if self._latency_bound is not None:
            wp.launch(kstep.hold_commands, dim=(W, M), inputs=[s.cmd, self._prev_cmd], device=dev)
        return False

    def _launch_cycle(self, c: int) -> None:
        """Cycle ``c`` of a step on the per-cycle path: integrate (+ bin into the grid), then detect. Two or three
        launches."""
        m, s, dev = self.model, self.state, self.device
        W, M = self.num_worlds, self.num_movers
        use_grid = M > 32
        if use_grid:
            wp.launch(kcol.clear_cells, dim=max(self._cell_head.shape[0], W), device=dev,
                      inputs=[self._cell_head, s.world_pairs, s.world_walls])
        head, nxt = (self._cell_head, self._next_in_cell) if use_grid else (self._no_cells, self._no_next)
        wp.launch(
            self._advance_kernel, dim=(W, M), device=dev, block_dim=self._block_dim(W * M),
            inputs=[m.limits, m.impedance, m.collision, m.tiles, m.body, m.radius, m.half_size, m.margins,
                    self._act_params, s.cmd, self._prev_cmd, self._delay, c, s.target_pos, s.target_quat,
                    s.force_aux, s.halted, s.pos, s.quat, s.vel, s.omega, s.acc, s.planar, s.wall, s.cycles, m.grid,
                    1 if use_grid else 0, head, nxt, s.world_pairs, s.world_walls],
        )
        self._launch_narrow_phase()

    def _launch_narrow_phase(self) -> None:
        m, s, dev = self.model, self.state, self.device
        W, M = self.num_worlds, self.num_movers
        outputs = [s.flags, s.flags_any, s.partner, s.world_pairs, s.world_walls, s.halted, s.pair_list]
        if M <= 32:
            wp.launch(kcol.detect_collisions_brute, dim=(W, M), device=dev, block_dim=self._block_dim(W * M),
                      inputs=[m.collision, m.radius, m.half_size, m.margins, s.pos, s.quat, s.wall, *outputs])
            return
        wp.launch(
            kcol.detect_collisions_grid, dim=(W, M), device=dev, block_dim=self._block_dim(W * M),
            inputs=[m.collision, m.grid, m.radius, m.half_size, m.margins, s.pos, s.quat, s.wall, self._cell_head,
                    self._next_in_cell, *outputs],
        )

    def _detect_pairs(self) -> None:
        """Mover-mover check and flag/counter outputs from the current poses and wall flags."""
        m, s, dev = self.model, self.state, self.device
        W, M = self.num_worlds, self.num_movers
        if M <= 32:
            wp.launch(kcol.clear_world_counters, dim=W, inputs=[s.world_pairs, s.world_walls], device=dev)
        else:
            wp.launch(kcol.clear_cells, dim=max(self._cell_head.shape[0], W), device=dev,
                      inputs=[self._cell_head, s.world_pairs, s.world_walls])
            wp.launch(kcol.bin_movers, dim=(W, M), inputs=[m.grid, s.pos, self._cell_head, self._next_in_cell],
                      device=dev)
        self._launch_narrow_phase()
