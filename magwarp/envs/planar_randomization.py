"""Domain randomisation on the planar simulator (:class:`magwarp.sim.Simulator`, the trajectory-planning env): the
event terms of :mod:`magwarp.envs.randomization` (same :class:`~magwarp.envs.randomization.EventTerm`, distributions,
operations, modes and seeding as the push envs) over the simulator's per-world model arrays, on the device, with no
rebuild and no recapture (the kernels read ``body[w, m]``, ``radius[w, m]``, ``half_size[w, m]``, ``margins[w]``).

Fields, one draw per target (movers; the margins: one per world), ``dim`` components each:

* ``mover_mass`` (kg): the mover's true mass. The planar law is acceleration commanded: the controller asks the
  drive for ``m_ctrl a`` with its own, configured mass ``m_ctrl`` (``MoverSpec.mass``), so the mover accelerates by
  ``a m_ctrl / m`` in x/y (F = m a: a heavier mover lags its commands); the levitation carries the true weight
  ``m g`` (no sag); the impedance hold of z and the attitude keeps its damping ``2 sqrt(K m_ctrl)`` (under-damped
  for a heavier mover: the z response to a force ``F`` is ``F / m`` at first). The principal inertia scales with the
  mass (uniform density) unless ``mover_inertia`` is randomised too.
* ``mover_inertia`` (3: principal moments, kg m^2): the attitude's true inertia (damping keeps the configured one).
* ``payload_mass`` (kg, op ``set``/``add``, nominal 0) at ``offset`` (x, y, z in the body frame from the mover
  centre): adds to the mass as above, moves the centre of mass by ``offset p / (m + p)`` (gravity then has a torque
  about the centre, where the levitation carries the weight; the impedance hold resists the tilt) and adds
  ``mu (|r|^2 - r_i^2)`` to the principal moments (parallel axis, ``mu = m p / (m + p)``; products of inertia
  dropped). ``known=True``: the controller is configured for the payload (XPlanar's payload parametrisation, as
  in the XBot's ``PayloadWeight`` setting): its mass becomes ``m_ctrl + p``, so the x/y motion follows the commands
  (F = (m_ctrl + p) a_cmd = (m + p) a with the nominal mover) and the z damping is ``2 sqrt(K (m_ctrl + p))``; the
  centre of mass, the inertia and the weight change as without it. Without it (the default) the payload is
  unknown to the controller, which then lags its commands like a heavier mover.
* ``stiffness_lin`` / ``stiffness_rot`` (3 each: x, y, z / roll, pitch, yaw): the impedance gains on the held axes;
  the damping follows, ``2 sqrt(K m_ctrl)`` / ``2 sqrt(K I_ctrl)`` (critical for the nominal mover). Their largest
  value must be stable at the cycle time for the lightest mover the terms allow (the simulator's own bound).
* ``v_max``, ``a_max``, ``j_max`` (per mover): the x/y limits the law clips to (norm clip of the command, speed cap).
* ``collision_radius`` (circles), ``collision_half_size`` (2: boxes), ``collision_margin`` and ``wall_margin`` (one
  per world): the per-cycle collision check's sizes. Starts and goals are still sampled with the built sizes: build
  the env with the largest size you draw (``collision_size``, ``safety_margin``) to keep starts collision free.
  Worlds of more than 32 movers (grid broad phase, its cells sized at build) refuse sizes above the built ones.

Every firing is one kernel launch (:func:`magwarp.kernels.randomize.fire_terms`, over (world, mover) threads: the
draws, the operations and the writes for the targeted worlds and movers, then the packing of their body rows), from the
torch step and from inside the fused step's graph alike. The draws come from Warp's counter-based generator keyed by the
env's seed (the one it was built with, then ``reset(seed=...)``'s), a per-world count of firings, and the term, mover
and component (each component its own generator state), not from the env's torch generator: the same seed reproduces
them, and the env's other draws (goals, starts) are those of an env without terms. (Until #24's cost work they were
torch draws from the env's generator, then, until its second cost pass, one generator state per world drawn in turn: the
values for a given seed changed each time.) ``interval`` terms fire before each simulated env step.
"""

from __future__ import annotations

import contextlib

import numpy as np
import torch
import warp as wp

from magwarp.envs.randomization import EventRunner, EventTerm, Gaussian, LogUniform
from magwarp.kernels import randomize as krand
from magwarp.kernels.params import MoverParams

__all__ = ["PlanarRandomizer"]

#: Threads per block of a firing's launch on CUDA (:attr:`PlanarRandomizer.fire_block`). Measured on an H100
#: (``python benchmarks/fire_cost.py --device cuda:0``, benchmarks/results/fire_cost_s34_gpu.json), us per reset
#: firing at 65,536 B0 envs with 6 % of the worlds resetting: 26.1 with Warp's 256 a block, 24.0 with 128, 20.0 with
#: 64, 20.2 with 32 (1 %: 16.3 against 10.95 with 64; 100 %: 78.4 against 77.4); in the B0 env step
#: (``benchmarks/rand_gaps.py --fire grid/b64``) full randomisation's cost fell from +27.98 % to +26.04 %.
FIRE_BLOCK_CUDA = 64


def default_fire_block(cuda: bool) -> int:
    """A firing's threads per block on a CUDA device (``cuda``): :data:`FIRE_BLOCK_CUDA`; on the CPU 0, Warp's default
    (a CPU launch runs its threads in a loop: a block size means little there)."""
    return FIRE_BLOCK_CUDA if cuda else 0


#: the body fields and their :attr:`magwarp.sim.Simulator.mover_params` keys
BODY_KEYS = {"mover_mass": "mass", "mover_inertia": "inertia", "payload_mass": "payload", "stiffness_lin": "k_lin",
             "stiffness_rot": "k_rot", "v_max": "v_max", "a_max": "a_max", "j_max": "j_max"}
SIZE_FIELDS = ("collision_radius", "collision_half_size", "collision_margin", "wall_margin")
#: the kernel's codes (:mod:`magwarp.kernels.randomize`)
FIELD_CODES = {"mover_mass": krand.MOVER_MASS, "mover_inertia": krand.MOVER_INERTIA, "payload_mass": krand.PAYLOAD_MASS,
               "stiffness_lin": krand.STIFFNESS_LIN, "stiffness_rot": krand.STIFFNESS_ROT, "v_max": krand.V_MAX,
               "a_max": krand.A_MAX, "j_max": krand.J_MAX, "collision_radius": krand.COLLISION_RADIUS,
               "collision_half_size": krand.COLLISION_HALF_SIZE, "collision_margin": krand.COLLISION_MARGIN,
               "wall_margin": krand.WALL_MARGIN}
MODE_CODES = {"startup": krand.MODE_STARTUP, "reset": krand.MODE_RESET, "interval": krand.MODE_INTERVAL}
OP_CODES = {"set": krand.OP_SET, "scale": krand.OP_SCALE, "add": krand.OP_ADD}


def rng_key(seed: int) -> int:
    """The kernel's int32 generator key for an env seed (any non-negative integer)."""
    k = (int(seed) ^ (int(seed) >> 32) ^ 0x5EED7E57) & 0xFFFFFFFF
    return k - (1 << 32) if k >= 1 << 31 else k


def _empty_mover_params(device):
    """:class:`~magwarp.kernels.params.MoverParams` with empty arrays, for a term table without body fields."""
    p = MoverParams()
    p.m_ctrl, p.i_ctrl, p.scale_inertia = 1.0, wp.vec3d(1.0, 1.0, 1.0), 0
    for name in ("mass", "payload", "known", "v_max", "a_max", "j_max"):
        setattr(p, name, wp.empty((0, 0), dtype=wp.float64, device=device))
    for name in ("inertia", "offset", "k_lin", "k_rot"):
        setattr(p, name, wp.empty((0, 0), dtype=wp.vec3d, device=device))
    return p


def _term_row(t: EventTerm, dim: int):
    """Term ``t`` (``dim`` components per target) as the kernel reads it (:class:`magwarp.kernels.randomize.Term`)."""
    d = t.dist
    row = krand.Term()
    row.field, row.dim = FIELD_CODES[t.field], dim
    if isinstance(d, Gaussian):
        row.dist, row.a, row.b = krand.GAUSSIAN, d.mean, d.std
        row.clip = int(d.clip is not None)
        row.lo, row.hi = d.clip if d.clip is not None else (0.0, 0.0)
    elif isinstance(d, LogUniform):
        row.dist, row.a, row.b = krand.LOG_UNIFORM, float(np.log(d.lo)), float(np.log(d.hi))
    else:
        row.dist, row.a, row.b = krand.UNIFORM, d.lo, d.hi
    row.op, row.mode = OP_CODES[t.op], MODE_CODES[t.mode]
    row.interval = int(t.interval_steps or 1)
    row.known = int(bool(t.known))
    row.offset = wp.vec3d(*(t.offset or (0.0, 0.0, 0.0)))
    return row


def pack_level(fields: set[str]) -> int:
    """How a firing that draws ``fields`` packs the body rows (:func:`magwarp.kernels.randomize.fire_terms`): not at
    all without a body field, only the limits (copied verbatim into the rows) when it draws only those, else whole.
    (The rows hold the parameters as last packed: writes into them from outside the terms need
    :meth:`PlanarRandomizer.commit`.)"""
    body = {f for f in fields if f in BODY_KEYS}
    if not body:
        return krand.PACK_NONE
    return krand.PACK_LIMITS if body <= {"v_max", "a_max", "j_max"} else krand.PACK_ALL


def item_plan(terms: list[tuple[str, str]], targets: list[list[int]]) -> dict[str, list[tuple[int, int, int]]]:
    """The kernel's items per mode: ``(term, target, later)``, term ``i`` (``terms[i]``: its field and mode) on each
    of its ``targets[i]``, in term order. ``later``: the index (in the mode's list) of the next item of the mode that
    writes the same field of the same target, -1 for none: of the items that fire in one launch, the last one of a
    field and target sets it. Every startup and reset term fires in its mode's launch, so those lists keep only the
    items with no later one (the others' draws would be overwritten; each component draws from its own generator
    state, so dropping them changes no other draw); the interval list keeps them all (which fire depends on the
    step count: the kernel walks ``later``)."""
    plans = {}
    for mode in MODE_CODES:
        pairs = [(i, m) for i, (_, md) in enumerate(terms) if md == mode for m in targets[i]]
        later = []
        for q, (i, m) in enumerate(pairs):
            nxt = [r for r in range(q + 1, len(pairs)) if terms[pairs[r][0]][0] == terms[i][0] and pairs[r][1] == m]
            later.append(nxt[0] if nxt else -1)
        plan = [(i, m, nx) for (i, m), nx in zip(pairs, later)]
        plans[mode] = plan if mode == "interval" else [(i, m, -1) for i, m, nx in plan if nx < 0]
    return plans


class PlanarRandomizer(EventRunner):
    """Applies :class:`~magwarp.envs.randomization.EventTerm` s to an env's planar simulator ``env.sim`` (see the
    module doc). ``values``/``nominal`` as in :class:`~magwarp.envs.randomization.EventRunner`; the body fields are
    float64 (the simulator's parameter tensors, :attr:`magwarp.sim.Simulator.mover_params`)."""

    BACKEND = "planar"

    def __init__(self, env, terms):
        self.sim = env.sim
        #: threads per block of the firing's launch (0: Warp's default); set it to switch (before a step graph is
        #: captured: the graph keeps the launch it captured)
        self.fire_block = default_fire_block(self.sim.device.is_cuda)
        super().__init__(env, terms, self.sim.num_worlds, self.sim.torch_device)
        self.sim.add_step_callback(self.step)

    def _resolve_targets(self, env, used) -> dict[str, int]:
        m = self.sim.num_movers
        circle = self.sim.mover.collision_shape == "circle"
        out = {f: m for f in BODY_KEYS}
        out.update({"collision_radius": m if circle else 0, "collision_half_size": 0 if circle else m,
                    "collision_margin": 1, "wall_margin": 1})
        return out

    def _nominal(self) -> dict[str, torch.Tensor]:
        sim, out = self.sim, {}
        if any(t.field in BODY_KEYS for t in self.terms):  # makes the body rows per world
            p = sim.mover_params
            out = {field: p[key][0].clone() for field, key in BODY_KEYS.items()}
        out.update({"collision_radius": sim.radii[0].clone(), "collision_half_size": sim.half_sizes[0].clone(),
                    "collision_margin": sim.margins[0, :1].clone(), "wall_margin": sim.margins[0, 1:].clone()})
        return out

    def _initial_values(self, used: set[str]) -> dict[str, torch.Tensor]:
        """The simulator's own per-world tensors (views): the terms write into them, and a commit is one kernel."""
        sim = self.sim
        views = {}
        if any(f in BODY_KEYS for f in used):
            views = {field: sim.mover_params[key] for field, key in BODY_KEYS.items()}
            self.payload_offset = sim.mover_params["payload_offset"]
            self.payload_known = sim.mover_params["payload_known"]
        views.update({"collision_radius": sim.radii, "collision_half_size": sim.half_sizes,
                      "collision_margin": sim.margins[:, :1], "wall_margin": sim.margins[:, 1:]})
        return {f: views[f] for f in used}

    def _prepare(self, used: set[str]) -> None:
        arrays = {"collision_radius": "radius", "collision_half_size": "half_size", "collision_margin": "margins",
                  "wall_margin": "margins"}
        for i, t in enumerate(self.terms):
            if t.field in ("stiffness_lin", "stiffness_rot"):
                self._check_stiffness(i, t)
            if t.field in SIZE_FIELDS and self.sim.num_movers > 32:
                built = float(self.nominal[t.field].max())
                top = self.extreme(t)[1]
                if top > built:
                    raise ValueError(f"randomization[{i}] ({t.field!r}) can grow it to {top:g} m, above the built "
                                     f"{built:g} m: worlds of more than 32 movers bin them in grid cells sized at "
                                     "build; build the env with the largest size")
        self.sim.make_per_world(*sorted({arrays[f] for f in used if f in arrays}))
        self._term_table()  # before any firing (never inside a captured step)

    def _check_stiffness(self, i: int, t: EventTerm) -> None:
        sim = self.sim
        rot = t.field == "stiffness_rot"
        held = sim.model.impedance.mask_rot if rot else sim.model.impedance.mask_lin
        if any(float(v) for v in held):
            self.check_stiffness_stable(i, t, float(sim.model.limits.dt), float(sim.mover.mass),
                                        float(np.min(np.asarray(sim.mover.inertia))))

    # ------------------------------------------------------------------ the kernel's inputs
    def _term_table(self) -> None:
        """The terms as the kernel reads them: per mode, its (term, target) pairs
        (:class:`magwarp.kernels.randomize.Item`, the startup and reset ones: only those that set a value, see
        :func:`item_plan`), on the device; the generator key and per-world counters."""
        sim, dev = self.sim, self.sim.device
        width = max(1, sim.num_movers)
        rows, targets = [], []
        for t in self.terms:
            count = self._targets[t.field]
            targets.append(list(t.targets) if t.targets is not None else list(range(count)))
            nom = self.nominal[t.field].detach().cpu().numpy().astype(np.float64).reshape(count, -1)
            rows.append((_term_row(t, nom.shape[1]), nom))
        self._items, self._first = {}, {}
        for mode, plan in item_plan([(t.field, t.mode) for t in self.terms], targets).items():
            # by target (stable: a field's items of one target keep their order), ``later`` renumbered to match
            order = sorted(range(len(plan)), key=lambda q: plan[q][1])
            where = {q: r for r, q in enumerate(order)}
            items = []
            for q in order:
                i, m, later = plan[q]
                row, nom = rows[i]
                it = krand.Item()
                it.t, it.target, it.stream = row, m, 3 * (i * width + m)
                it.later = where[later] if later >= 0 else -1
                it.nominal = wp.vec3d(*nom[m], *([0.0] * (3 - nom.shape[1])))
                items.append(it)
            self._items[mode] = (wp.array(items, dtype=krand.Item, device=dev) if items
                                 else wp.empty(0, dtype=krand.Item, device=dev))
            counts = np.bincount([plan[q][1] for q in order], minlength=width)
            self._first[mode] = wp.array(np.concatenate([[0], np.cumsum(counts)]).astype(np.int32), dtype=wp.int32,
                                         device=dev)
        # targets per thread: one on a GPU (a firing's latency is one target's items and one mover's packing), all of
        # a world's on the CPU (a thread's setup dominates there); the draws do not depend on it
        self._per_thread = 1 if sim.device.is_cuda else width
        self._key = torch.tensor([rng_key(self.env._generator.initial_seed())], dtype=torch.int32,
                                 device=self.device)
        # the firings drawn per world, one copy per target (the thread that fires a target advances its copy)
        self._counter = torch.zeros(self.num_worlds, width, dtype=torch.int32, device=self.device)
        self._all = wp.ones(1, dtype=wp.bool, device=dev)  # the mask placeholder when every world fires
        self._body = any(t.field in BODY_KEYS for t in self.terms)
        # terms of the collision sizes only: empty parameter arrays (the kernel writes no body field then)
        self._empty_params = None if self._body else _empty_mover_params(dev)

    def reseed(self, seed: int) -> None:
        """``reset(seed=...)``: the draws from here on follow ``seed`` (as for an env built with it, after startup)."""
        self._key.fill_(rng_key(seed))
        self._counter.zero_()

    # ------------------------------------------------------------------ firing
    def _fire(self, mode: str, mask: torch.Tensor | None, current_stream: bool = False) -> bool:
        """Launch the kernel for the terms of ``mode`` due now (interval: their period divides the step count), for the
        worlds in ``mask`` (all if None); nothing when none is due. ``current_stream``: on Warp's current stream (inside
        a captured env step), else on the simulator's."""
        due = [t for t in self.terms if t.mode == mode and (mode != "interval" or self.steps % t.interval_steps == 0)]
        if not due:
            return False
        sim = self.sim
        params = sim.mover_param_struct(self._scale_inertia()) if self._body else self._empty_params
        m = sim.model
        mask_wp = self._all if mask is None else wp.from_torch(mask, dtype=wp.bool)
        pack = pack_level({t.field for t in due})
        width = self._counter.shape[1]
        with contextlib.nullcontext() if current_stream else sim._on_stream():
            wp.launch(krand.fire_terms, dim=(self.num_worlds, -(-width // self._per_thread)), device=sim.device,
                      block_dim=int(self.fire_block) or None,
                      inputs=[MODE_CODES[mode], int(self.steps), int(mask is None), mask_wp, self._per_thread, pack,
                              self._items[mode], self._first[mode], wp.from_torch(self._key),
                              wp.from_torch(self._counter)],
                      outputs=[params, m.radius, m.half_size, m.margins, m.body])
        return True

    def _scale_inertia(self) -> bool:
        used = self.values
        return "mover_mass" in used and "mover_inertia" not in used

    def reset(self, mask: torch.Tensor) -> None:
        """Reset-mode terms for the worlds in ``mask`` (``[W]`` bool on the device): one launch, no host sync."""
        self._fire("reset", mask)

    def step(self) -> None:
        """Count an env step; interval terms whose period divides the count fire (all worlds, one launch)."""
        self.steps += 1
        self._fire("interval", None)

    def commit(self, mask: torch.Tensor | None, current_stream: bool = False) -> None:
        """Pack the body fields of the worlds in ``mask`` (all if None) from the simulator's parameter tensors (after
        writes into them from outside the terms): one kernel. The terms' own firings pack after they draw."""
        if any(f in self.values for f in BODY_KEYS):
            self.sim.commit_mover_params(mask, scale_inertia=self._scale_inertia(), current_stream=current_stream)

    def reset_in_step(self, mask: torch.Tensor) -> None:
        """:meth:`reset` inside an env step (the fused step, possibly being captured as a CUDA graph): the same
        launch, on Warp's current stream. ``mask``: a device tensor (no host sync)."""
        self._fire("reset", mask, current_stream=True)
