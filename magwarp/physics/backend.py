"""Batched mujoco-warp backend: many worlds of one MJCF model, movers driven by :mod:`magwarp.physics.control`.

One call of :meth:`MjwBackend.step` runs ``num_cycles`` control cycles (control kernel -> ``mujoco_warp.step`` ->
per-cycle hooks) for all worlds. The whole sequence is recorded once as a Warp graph and replayed, on CUDA and on
CPU alike (Warp 1.19 records CPU graphs; mujoco-warp's step captures on CPU). Inputs are written into fixed buffers
before each replay, so no allocation or host<->device sync happens inside a step. Resets by mask are a second graph
(``mujoco_warp.reset_data`` restricted to the mask, then a copy of per-world initial ``qpos``/``qvel``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch
import warp as wp

from magwarp._checks import MAGNITUDE_MAX, as_count
from magwarp._streams import gc_paused, torch_stream
from magwarp.physics.control import (
    YawDrive,
    copy_rows_masked_kernel,
    mover_control_kernel,
    zero_float_masked_kernel,
    zero_vec2_masked_kernel,
)

__all__ = ["CONTROL_CYCLE_S", "PHYSICS_DT_MAX", "PHYSICS_DT_MIN", "ControlParams", "MjwBackend", "PhysicsInputError",
           "physics_substeps"]


class PhysicsInputError(ValueError):
    """An input (action, mask, state, option) that the backend cannot use."""


def _yaw_drive(c: ControlParams) -> YawDrive:
    """The yaw drive's kernel struct from the (frozen) control parameters."""
    yaw = YawDrive()
    yaw.enabled, yaw.jerk_mode = int(c.rotation), int(c.jerk)
    yaw.v_max, yaw.a_max, yaw.j_max = float(c.v_max_c), float(c.a_max_c), float(c.j_max_c)
    yaw.p_max = float(c.p_max_c) if c.p_max_c is not None else -1.0
    return yaw


#: The control cycle of MagBotSim and of the real system (s): envs count an env step in these cycles.
CONTROL_CYCLE_S = 0.001
#: The largest physics step (s) the push envs accept. Two bounds meet here: MuJoCo's contact time constant (default
#: solref 0.02 s) is raised to at least 2 x timestep when it is shorter (refsafe), so steps above 10 ms would
#: silently soften every contact; and a mover at v_max = 2 m/s moves v_max x dt per step, 1 cm at 5 ms, half the
#: half-thickness of the thinnest default object part (T/L/X segments, 0.02 m), so nothing tunnels. 5 ms keeps a
#: factor of 2 on both.
PHYSICS_DT_MAX = 0.005
#: the smallest physics step (s): every physics step is a mujoco-warp step recorded into the step graph, so below
#: 0.1 ms (10 per 1 ms control cycle, 400 per 40-cycle env step) the graph and its build time grow without a use (the
#: real system's cycle is 1 ms); values such as 1e-300 would ask for more steps than any count holds
PHYSICS_DT_MIN = 1e-4


def physics_substeps(physics_dt, num_cycles: int) -> int:
    """Physics steps per env step of ``num_cycles`` control cycles of :data:`CONTROL_CYCLE_S` at ``physics_dt`` (s).

    ``physics_dt`` must be a finite number in [:data:`PHYSICS_DT_MIN`, :data:`PHYSICS_DT_MAX`] that divides the env
    step (``num_cycles`` ms) into a whole number of steps; anything else raises :class:`PhysicsInputError` naming it."""
    if isinstance(physics_dt, (bool, np.bool_)) or not isinstance(physics_dt, (int, float, np.integer, np.floating)):
        raise PhysicsInputError(f"physics_dt must be a number of seconds, got {physics_dt!r}")
    dt = float(physics_dt)
    if not np.isfinite(dt) or dt <= 0:
        raise PhysicsInputError(f"physics_dt must be a positive, finite number of seconds, got {physics_dt!r}")
    if dt < PHYSICS_DT_MIN * (1 - 1e-9):
        raise PhysicsInputError(
            f"physics_dt={physics_dt!r} s is below {PHYSICS_DT_MIN} s: each physics step is a mujoco-warp step "
            "recorded into the step graph (at most 10 per 1 ms control cycle)")
    if dt > PHYSICS_DT_MAX * (1 + 1e-9):
        raise PhysicsInputError(
            f"physics_dt={physics_dt!r} s is above {PHYSICS_DT_MAX} s: MuJoCo would soften the contacts (time constant "
            f"0.02 s < 2 physics_dt near 10 ms) and a mover at 2 m/s would move over 1 cm per physics step")
    step = int(num_cycles) * CONTROL_CYCLE_S
    ratio = step / dt
    n = int(round(ratio))
    if n < 1 or abs(ratio - n) > 1e-6 * ratio:
        raise PhysicsInputError(f"physics_dt={physics_dt!r} s does not divide the env step of {int(num_cycles)} "
                                f"control cycles ({step:g} s) into whole physics steps (ratio {ratio:.6g})")
    return n


@dataclass(frozen=True)
class ControlParams:
    """Mover control limits and impedance gains (MagBotSim's RL-env defaults).

    ``jerk``: commands are jerks (else accelerations). Stiffness: translational (x, y, z) — only z is used, x/y are
    commanded — and rotational (roll, pitch, yaw). ``rotation``: a third command per mover drives the yaw ("c",
    MagBotSim's ``learn_mover_c_rotation``) within ``v_max_c`` (rad/s), ``a_max_c`` (rad/s^2), ``j_max_c``
    (rad/s^3, jerk mode) and, if set, ``|yaw| <= p_max_c`` (rad, at most pi); see :mod:`magwarp.physics.control`.
    """

    v_max: float = 2.0
    a_max: float = 10.0
    j_max: float = 100.0
    jerk: bool = False
    k_lin: tuple[float, float, float] = (1.0, 1.0, 100.0)
    k_rot: tuple[float, float, float] = (0.1, 0.1, 1.0)
    num_cycles: int = 40
    rotation: bool = False
    v_max_c: float = 122.17305
    a_max_c: float = 122.17305
    j_max_c: float = 610.86524
    p_max_c: float | None = None

    def __post_init__(self):
        if self.p_max_c is not None and not (np.isfinite(self.p_max_c) and 0.0 < self.p_max_c <= np.pi):
            raise PhysicsInputError(f"ControlParams.p_max_c must be None or in (0, pi], got {self.p_max_c!r}")
        for name in ("v_max", "a_max", "j_max", "v_max_c", "a_max_c", "j_max_c"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0 or v > MAGNITUDE_MAX:
                raise PhysicsInputError(f"ControlParams.{name} must be positive, finite and at most {MAGNITUDE_MAX:g} "
                                        f"(a step's float32 arithmetic would overflow), got {v!r}")
        for name in ("k_lin", "k_rot"):
            v = tuple(float(x) for x in getattr(self, name))
            if len(v) != 3 or not all(np.isfinite(x) and x >= 0 for x in v):
                raise PhysicsInputError(f"ControlParams.{name} must be three non-negative numbers, got {v!r}")
            object.__setattr__(self, name, v)
        if int(self.num_cycles) != self.num_cycles or self.num_cycles < 1:
            raise PhysicsInputError(f"ControlParams.num_cycles must be a positive integer, got {self.num_cycles!r}")


def _free_joint_addrs(mjm: mujoco.MjModel, body_names: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(body ids, qpos addresses, dof addresses) of the free joint of each named body."""
    ids, qadr, dadr = [], [], []
    for name in body_names:
        bid = mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_BODY, name)
        if bid < 0:
            raise PhysicsInputError(f"body {name!r} not found in the model")
        jnt = mjm.body_jntadr[bid]
        if mjm.body_jntnum[bid] < 1 or mjm.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
            raise PhysicsInputError(f"body {name!r} has no free joint as its first joint")
        ids.append(bid)
        qadr.append(mjm.jnt_qposadr[jnt])
        dadr.append(mjm.jnt_dofadr[jnt])
    return np.array(ids, dtype=np.int32), np.array(qadr, dtype=np.int32), np.array(dadr, dtype=np.int32)


def _strided_view(t: torch.Tensor, starts: np.ndarray, width: int) -> torch.Tensor | None:
    """``t[:, starts[k]:starts[k]+width]`` for all k as one ``[W, K, width]`` view; None unless starts are evenly spaced."""
    if len(starts) == 0:
        return t[:, :0].reshape(t.shape[0], 0, width)
    step = int(starts[1] - starts[0]) if len(starts) > 1 else width
    if len(starts) == 1 or (step > 0 and np.all(np.diff(starts) == step)):
        return t.as_strided((t.shape[0], len(starts), width), (t.stride(0), step * t.stride(1), t.stride(1)), int(starts[0]))
    return None  # e.g. a hook gave only some movers extra joints: use qpos_t/qvel_t with mover_qadr/mover_dadr


class MjwBackend:
    """Steps ``num_worlds`` copies of an MJCF model with mujoco-warp; movers named ``mover_{k}`` are controlled.

    :param xml: MJCF string (e.g. from :func:`magwarp.mjcf.generate_mjcf`) or a compiled ``mujoco.MjModel``.
    :param num_worlds: number of parallel worlds.
    :param control: limits, gains and cycles per step.
    :param hover_z: target height of each mover's centre; default: the model's initial height of each mover.
    :param nconmax/njmax: contacts and constraint rows per world (mujoco-warp's per-world limits).
    :param device: Warp device (``"cpu"``, ``"cuda:0"``, ...); default Warp's default device.
    :param use_graph: record step/reset as Warp graphs (default); ``False`` runs kernels eagerly (debugging).
    """

    def __init__(
        self,
        xml: str | mujoco.MjModel,
        num_worlds: int,
        *,
        control: ControlParams | None = None,
        hover_z: float | np.ndarray | None = None,
        nconmax: int = 16,
        njmax: int = 64,
        device: str | wp.context.Device | None = None,
        use_graph: bool = True,
    ):
        import mujoco_warp as mjw

        self._mjw = mjw
        try:
            self.num_worlds = as_count(num_worlds, "num_worlds")
        except (TypeError, ValueError) as e:
            raise PhysicsInputError(f"num_worlds must be a positive integer, got {num_worlds!r}") from e
        self.control = control or ControlParams()
        if not isinstance(self.control, ControlParams):
            raise PhysicsInputError(f"control must be a ControlParams, got {type(self.control).__name__}")
        self._yaw_drive = _yaw_drive(self.control)
        self.device = wp.get_device(device)
        self.use_graph = bool(use_graph)
        # On CUDA, launch on torch's current stream so Warp kernels and torch ops on the views are ordered without
        # host synchronisation (the same convention as magwarp.sim).
        self._stream = (
            torch_stream(str(self.device)) if self.device.is_cuda else None
        )
        self.mjm = xml if isinstance(xml, mujoco.MjModel) else mujoco.MjModel.from_xml_string(xml)
        mjd, mass, inertia = self._read_model(hover_z)
        self._alloc_device(mjd, mass, inertia, int(nconmax), int(njmax))
        self._cycle_hooks: list[Callable[[], None]] = []
        self._step_hooks: list[Callable[[], None]] = []
        self._record_stream = None  # set by recording(): launch into an outer capture instead of replaying graphs
        self._step_graph = None
        self._reset_graph = None
        #: per-world model arrays made by :meth:`batch_model_fields` (name -> torch view ``[W, ...]``)
        self.batched_fields: dict[str, torch.Tensor] = {}
        self._make_torch_views()

    # ------------------------------------------------------------------ construction parts
    def _read_model(self, hover_z) -> tuple[mujoco.MjData, np.ndarray, np.ndarray]:
        """The movers and objects of the MuJoCo model (bodies ``mover_i`` / ``object_i`` with free joints), its time
        step and the movers' hover heights; returns the initial data (after ``mj_forward``), the mass riding on each
        mover (its subtree) and the principal inertia of each mover body."""
        mjm = self.mjm
        self.dt = float(mjm.opt.timestep)
        mover_names = []
        while mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_BODY, f"mover_{len(mover_names)}") >= 0:
            mover_names.append(f"mover_{len(mover_names)}")
        self.num_movers = len(mover_names)
        object_names = []
        while mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_BODY, f"object_{len(object_names)}") >= 0:
            object_names.append(f"object_{len(object_names)}")
        self.num_objects = len(object_names)
        self.mover_body, self.mover_qadr, self.mover_dadr = _free_joint_addrs(mjm, mover_names)
        self.object_body, self.object_qadr, self.object_dadr = _free_joint_addrs(mjm, object_names)

        mjd = mujoco.MjData(mjm)
        mujoco.mj_forward(mjm, mjd)
        mass = mjm.body_subtreemass[self.mover_body].astype(np.float64)
        inertia = mjm.body_inertia[self.mover_body].astype(np.float64)
        if hover_z is None:
            hz = mjd.qpos[self.mover_qadr + 2].copy() if self.num_movers else np.zeros(0)
        else:
            hz = np.broadcast_to(np.asarray(hover_z, dtype=np.float64), (self.num_movers,)).copy()
            if not np.all(np.isfinite(hz)):
                raise PhysicsInputError(f"hover_z must be finite, got {hover_z!r}")
        self.hover_z = hz
        return mjd, mass, inertia

    def _alloc_device(self, mjd: mujoco.MjData, mass: np.ndarray, inertia: np.ndarray, nconmax: int,
                      njmax: int) -> None:
        """mujoco-warp's model and data for every world, the movers' drive parameters, commands and the start state
        on the device."""
        mjw, mjm, c = self._mjw, self.mjm, self.control
        with wp.ScopedDevice(self.device):
            self.model = mjw.put_model(mjm)
            self.data = mjw.put_data(mjm, mjd, nworld=self.num_worlds, nconmax=nconmax, njmax=njmax)
            W, M = self.num_worlds, self.num_movers
            self._qadr = wp.array(self.mover_qadr, dtype=int)
            self._dadr = wp.array(self.mover_dadr, dtype=int)
            self._mass = wp.array(mass.reshape(1, -1) if M else np.zeros((1, 1)), dtype=float)
            self._inertia = wp.array(inertia, dtype=wp.vec3)
            self._hover_z = wp.array(self.hover_z, dtype=float)
            self._gains = wp.array(np.tile([c.k_lin[2], *c.k_rot], (1, max(M, 1), 1)), dtype=wp.vec4)
            self._limits = wp.array(np.tile([c.v_max, c.a_max, c.j_max], (1, max(M, 1), 1)), dtype=wp.vec3)
            self.cmd = wp.zeros((W, max(M, 1)), dtype=wp.vec2)
            self.acc = wp.zeros((W, max(M, 1)), dtype=wp.vec2)
            self.cmd_c = wp.zeros((W, max(M, 1)), dtype=float)  # yaw commands (control.rotation)
            self.acc_c = wp.zeros((W, max(M, 1)), dtype=float)
            self.yaw_track = wp.zeros((W, max(M, 1)), dtype=wp.vec2)
            self.reset_mask = wp.zeros(W, dtype=bool)
            self.init_qpos = wp.array(np.tile(mjd.qpos, (W, 1)), dtype=float)
            self.init_qvel = wp.array(np.tile(mjd.qvel, (W, 1)), dtype=float)
            self.init_mocap_pos = wp.array(np.tile(mjd.mocap_pos, (W, 1, 1)), dtype=wp.vec3) if mjm.nmocap else None
            self.init_mocap_quat = wp.array(np.tile(mjd.mocap_quat, (W, 1, 1)), dtype=wp.quat) if mjm.nmocap else None

    # ------------------------------------------------------------------ torch views
    def _make_torch_views(self):
        d = self.data
        self.qpos_t = wp.to_torch(d.qpos)
        self.qvel_t = wp.to_torch(d.qvel)
        self.qacc_t = wp.to_torch(d.qacc)
        self.cmd_t = wp.to_torch(self.cmd)  # [W, M, 2]
        self.acc_t = wp.to_torch(self.acc)
        self.cmd_c_t = wp.to_torch(self.cmd_c)  # [W, M]
        self.acc_c_t = wp.to_torch(self.acc_c)
        self.reset_mask_t = wp.to_torch(self.reset_mask)
        self.init_qpos_t = wp.to_torch(self.init_qpos)
        self.init_qvel_t = wp.to_torch(self.init_qvel)
        #: ``[W, M, 7]`` views of mover free-joint qpos (x, y, z, qw, qx, qy, qz) and ``[W, M, 6]`` qvel
        #: (world linear velocity, body-frame angular velocity); same for objects. ``None`` if user hooks made the
        #: joint addresses unevenly spaced (then index ``qpos_t``/``qvel_t`` with ``mover_qadr``/``mover_dadr``).
        self.mover_qpos = _strided_view(self.qpos_t, self.mover_qadr, 7)
        self.mover_qvel = _strided_view(self.qvel_t, self.mover_dadr, 6)
        self.mover_qacc = _strided_view(self.qacc_t, self.mover_dadr, 6)
        self.object_qpos = _strided_view(self.qpos_t, self.object_qadr, 7)
        self.object_qvel = _strided_view(self.qvel_t, self.object_dadr, 6)
        self.init_mover_qpos = _strided_view(self.init_qpos_t, self.mover_qadr, 7)
        self.init_mover_qvel = _strided_view(self.init_qvel_t, self.mover_dadr, 6)
        self.init_object_qpos = _strided_view(self.init_qpos_t, self.object_qadr, 7)
        self.init_object_qvel = _strided_view(self.init_qvel_t, self.object_dadr, 6)
        if self.mjm.nmocap:
            self.mocap_pos = wp.to_torch(self.data.mocap_pos)
            self.mocap_quat = wp.to_torch(self.data.mocap_quat)
            self.init_mocap_pos_t = wp.to_torch(self.init_mocap_pos)
            self.init_mocap_quat_t = wp.to_torch(self.init_mocap_quat)

    @property
    def torch_device(self) -> torch.device:
        return self.qpos_t.device

    # ------------------------------------------------------------------ per-world model fields
    def batch_model_fields(self, names: Sequence[str]) -> dict[str, torch.Tensor]:
        """Give each world its own copy of the mujoco-warp model arrays ``names`` (e.g. ``geom_pos``, ``geom_size``):
        mujoco-warp reads model arrays at ``worldid % shape[0]``, so a leading size of ``num_worlds`` makes them
        per world (geometry that changes per episode without a model rebuild). Returns ``{name: torch view
        [W, ...]}`` (also kept in ``batched_fields``); write the rows of the worlds to change, e.g. at a reset.
        Drops the recorded step graph (its kernels took the old arrays)."""
        out = {}
        with wp.ScopedDevice(self.device):
            for name in names:
                old = getattr(self.model, name, None)
                if not isinstance(old, wp.array):
                    raise PhysicsInputError(f"{name!r} is not an array field of the mujoco-warp model")
                if old.shape[0] != self.num_worlds:
                    host = old.numpy()
                    new = wp.array(np.repeat(host[:1], self.num_worlds, axis=0), dtype=old.dtype)
                    setattr(self.model, name, new)
                out[name] = wp.to_torch(getattr(self.model, name))
        self.batched_fields.update(out)
        self._step_graph = None
        self._reset_graph = None
        return out

    def batch_control(self) -> dict[str, torch.Tensor]:
        """Give each world its own row of the control law's mass, gains and limits (one row shared by all worlds until
        then): ``{"mass": [W, M] (kg: the drive force is mass x commanded acceleration, the z damping 2 sqrt(K_z
        mass)), "gains": [W, M, 4] (K_z, K_roll, K_pitch, K_yaw), "limits": [W, M, 3] (v_max, a_max, j_max)}``
        float32 torch views; write the rows of the worlds to change between steps. Drops the recorded graphs."""
        for name in ("_mass", "_gains", "_limits"):
            old = getattr(self, name)
            if old.shape[0] != self.num_worlds:
                rows = np.repeat(old.numpy(), self.num_worlds, axis=0)
                setattr(self, name, wp.array(rows, dtype=old.dtype, device=self.device))
        self._step_graph = None
        self._reset_graph = None
        return {"mass": wp.to_torch(self._mass), "gains": wp.to_torch(self._gains),
                "limits": wp.to_torch(self._limits)}

    # ------------------------------------------------------------------ hooks
    def add_cycle_hook(self, fn: Callable[[], None]) -> None:
        """Register ``fn()`` (which launches Warp kernels) to run after every ``mujoco_warp.step`` inside the step graph.

        Hooks are how per-cycle checks (contacts, collisions, corrective-movement counters) stay inside one graph.
        Registering a hook drops the recorded graph; it is re-recorded at the next step.
        """
        self._cycle_hooks.append(fn)
        self._step_graph = None

    def add_step_hook(self, fn: Callable[[], None]) -> None:
        """Register ``fn()`` (which issues Warp operations) to run once at the start of every step, inside the step
        graph, before the first cycle (e.g. clearing per-step flags without a separate launch from Python).
        Registering a hook drops the recorded graph."""
        self._step_hooks.append(fn)
        self._step_graph = None

    @contextlib.contextmanager
    def recording(self, stream: wp.Stream):
        """Inside an outer capture on ``stream`` (e.g. a torch CUDA graph of a whole env step): :meth:`step` and
        :meth:`reset` issue their kernels on ``stream`` directly, so they join the outer graph, instead of replaying
        their own graphs (a graph cannot be launched into a capture)."""
        previous = self._record_stream
        self._record_stream = stream
        try:
            yield
        finally:
            self._record_stream = previous

    # ------------------------------------------------------------------ stepping
    def apply_control(self) -> None:
        """Launch one cycle of the mover control law (writes ``qfrc_applied``, updates the command states); the step
        graph runs it before every ``mujoco_warp.step``. Public for tests and custom stepping loops."""
        c = self.control
        wp.launch(
            mover_control_kernel,
            dim=(self.num_worlds, self.num_movers),
            inputs=[
                self._qadr, self._dadr, self._mass, self._inertia, self._hover_z, self._gains, self._limits,
                self.dt, int(c.jerk), self._yaw_drive, self.data.qpos, self.data.qvel, self.cmd, self.cmd_c, self.acc,
                self.acc_c, self.yaw_track,
            ],
            outputs=[self.data.qfrc_applied],
            device=self.device,
        )

    def _launch_cycles(self):
        for hook in self._step_hooks:
            hook()
        for _ in range(self.control.num_cycles):
            if self.num_movers:
                self.apply_control()
            self._mjw.step(self.model, self.data)
            for hook in self._cycle_hooks:
                hook()

    def _launch_reset(self):
        W = self.num_worlds
        d = self.data
        self._mjw.reset_data(self.model, d, reset=self.reset_mask)
        wp.launch(copy_rows_masked_kernel, dim=(W, self.mjm.nq), inputs=[self.reset_mask, self.init_qpos], outputs=[d.qpos],
                  device=self.device)
        wp.launch(copy_rows_masked_kernel, dim=(W, self.mjm.nv), inputs=[self.reset_mask, self.init_qvel], outputs=[d.qvel],
                  device=self.device)
        if self.num_movers:
            for state in (self.acc, self.yaw_track):
                wp.launch(zero_vec2_masked_kernel, dim=(W, self.num_movers), inputs=[self.reset_mask], outputs=[state],
                          device=self.device)
            wp.launch(zero_float_masked_kernel, dim=(W, self.num_movers), inputs=[self.reset_mask], outputs=[self.acc_c],
                      device=self.device)
        if self.mjm.nmocap:
            self._copy_mocap()

    def _copy_mocap(self):
        W, nm = self.num_worlds, self.mjm.nmocap
        d = self.data
        wp.launch(_copy_mocap_kernel, dim=(W, nm),
                  inputs=[self.reset_mask, self.init_mocap_pos, self.init_mocap_quat],
                  outputs=[d.mocap_pos, d.mocap_quat], device=self.device)

    def _on_stream(self):
        return wp.ScopedStream(self._stream) if self._stream is not None else contextlib.nullcontext()

    def _run(self, attr: str, launcher: Callable[[], None]):
        if self._record_stream is not None:
            # no wait on the previous stream: inside a capture that would join a stream outside the graph
            with wp.ScopedDevice(self.device), wp.ScopedStream(self._record_stream, sync_enter=False):
                launcher()
            return
        with wp.ScopedDevice(self.device), self._on_stream():
            if not self.use_graph:
                launcher()
                return
            graph = getattr(self, attr)
            if graph is None:
                # Modules must be loaded before a capture (no compiling inside one; force_module_load would compile
                # every registered module): this first, eager call loads exactly the kernels used and is a real
                # step/reset. The capture that follows records without executing.
                launcher()
                # CUDA cannot capture on torch's default (legacy) stream: capture on a stream of our own, replay
                # on torch's.
                cuda = self.device.is_cuda
                capture_stream = wp.Stream(self.device) if cuda else None
                with gc_paused(cuda), wp.ScopedStream(capture_stream) if cuda else contextlib.nullcontext():
                    with wp.ScopedCapture(device=self.device, force_module_load=False) as cap:
                        launcher()
                setattr(self, attr, cap.graph)
                return
            wp.capture_launch(graph, stream=self._stream)

    def _check_actions(self, actions) -> torch.Tensor:
        W, M = self.num_worlds, self.num_movers
        if isinstance(actions, wp.array):
            actions = wp.to_torch(actions)
        if isinstance(actions, np.ndarray):
            raise PhysicsInputError(
                f"actions must be a torch.Tensor on {self.torch_device}, got a numpy array (use torch.as_tensor(a, device=...))"
            )
        if not isinstance(actions, torch.Tensor):
            raise PhysicsInputError(f"actions must be a torch.Tensor, got {type(actions).__name__}")
        if not actions.is_floating_point():
            raise PhysicsInputError(f"actions must be a floating-point tensor, got dtype {actions.dtype}")
        if actions.device != self.torch_device:
            raise PhysicsInputError(f"actions are on device {actions.device}, but the backend runs on {self.torch_device}")
        d = 3 if self.control.rotation else 2
        if tuple(actions.shape) not in ((W, M, d), (W, d * M)):
            raise PhysicsInputError(f"actions must have shape ({W}, {M}, {d}) or ({W}, {d * M}), got {tuple(actions.shape)}")
        return actions.reshape(W, M, d)

    def set_actions(self, actions, check_finite: bool = True) -> None:
        """Write x/y commands (acceleration or jerk, per ``control.jerk``) for all worlds: shape ``[W, M, 2]`` or ``[W, 2M]``
        (with ``control.rotation``: x, y and yaw per mover, ``[W, M, 3]`` or ``[W, 3M]``).

        ``check_finite`` rejects NaN/inf with an error naming the first bad world and mover (costs one device sync).
        """
        a = self._check_actions(actions)
        if check_finite:
            bad = ~torch.isfinite(a)
            if bool(bad.any()):
                w, k, j = (int(v) for v in torch.nonzero(bad)[0])
                raise PhysicsInputError(
                    f"actions contain a non-finite value {float(a[w, k, j])} at world {w}, mover {k}, axis {j}"
                )
        if self.num_movers:
            self.cmd_t.copy_(a[..., :2])
            if self.control.rotation:
                self.cmd_c_t.copy_(a[..., 2])

    def step(self, actions=None, check_finite: bool = True) -> None:
        """Set ``actions`` (if given) and run ``control.num_cycles`` cycles in all worlds (one graph replay)."""
        if actions is not None:
            self.set_actions(actions, check_finite=check_finite)
        self._run("_step_graph", self._launch_cycles)

    def _check_mask(self, mask) -> torch.Tensor:
        W = self.num_worlds
        if not isinstance(mask, torch.Tensor):
            raise PhysicsInputError(f"reset mask must be a torch.Tensor of shape ({W},), got {type(mask).__name__}")
        if mask.dtype != torch.bool:
            raise PhysicsInputError(f"reset mask must have dtype torch.bool, got {mask.dtype}")
        if tuple(mask.shape) != (W,):
            raise PhysicsInputError(f"reset mask must have shape ({W},), got {tuple(mask.shape)}")
        if mask.device != self.torch_device:
            raise PhysicsInputError(f"reset mask is on device {mask.device}, but the backend runs on {self.torch_device}")
        return mask

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Reset the worlds where ``mask`` is True (all if None) to ``init_qpos``/``init_qvel`` (set them first).

        Other worlds are untouched. No model rebuild: change ``init_*`` views (e.g. sampled start poses) and reset.
        """
        if mask is None:
            self.reset_mask_t.fill_(True)
        else:
            self.reset_mask_t.copy_(self._check_mask(mask))
        self._run("_reset_graph", self._launch_reset)

    def forward(self) -> None:
        """Recompute derived quantities (positions, contacts) from qpos/qvel without stepping (e.g. after a reset)."""
        with wp.ScopedDevice(self.device), self._on_stream():
            self._mjw.forward(self.model, self.data)


@wp.kernel
def _copy_mocap_kernel(
    # In:
    mask: wp.array[bool],
    src_pos: wp.array2d[wp.vec3],
    src_quat: wp.array2d[wp.quat],
    # Out:
    dst_pos: wp.array2d[wp.vec3],
    dst_quat: wp.array2d[wp.quat],
):
    w, k = wp.tid()
    if mask[w]:
        dst_pos[w, k] = src_pos[w, k]
        dst_quat[w, k] = src_quat[w, k]
