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

Draws use the env's generator (``seed``, ``reset(seed=...)``): with terms on, the env's later draws (goals, starts)
differ from an env without them. ``interval`` terms fire before each simulated env step.
"""

from __future__ import annotations

import numpy as np
import torch

from magwarp.envs.randomization import EventRunner, EventTerm

__all__ = ["PlanarRandomizer"]

#: the body fields and their :attr:`magwarp.sim.Simulator.mover_params` keys
BODY_KEYS = {"mover_mass": "mass", "mover_inertia": "inertia", "payload_mass": "payload", "stiffness_lin": "k_lin",
             "stiffness_rot": "k_rot", "v_max": "v_max", "a_max": "a_max", "j_max": "j_max"}
SIZE_FIELDS = ("collision_radius", "collision_half_size", "collision_margin", "wall_margin")


class PlanarRandomizer(EventRunner):
    """Applies :class:`~magwarp.envs.randomization.EventTerm` s to an env's planar simulator ``env.sim`` (see the
    module doc). ``values``/``nominal`` as in :class:`~magwarp.envs.randomization.EventRunner`; the body fields are
    float64 (the simulator's parameter tensors, :attr:`magwarp.sim.Simulator.mover_params`)."""

    BACKEND = "planar"

    def __init__(self, env, terms):
        self.sim = env.sim
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

    def _check_stiffness(self, i: int, t: EventTerm) -> None:
        sim = self.sim
        rot = t.field == "stiffness_rot"
        held = sim.model.impedance.mask_rot if rot else sim.model.impedance.mask_lin
        if any(float(v) for v in held):
            self.check_stiffness_stable(i, t, float(sim.model.limits.dt), float(sim.mover.mass),
                                        float(np.min(np.asarray(sim.mover.inertia))))

    # ------------------------------------------------------------------ model writes
    def commit(self, mask: torch.Tensor | None, current_stream: bool = False) -> None:
        """Pack the body fields of the worlds in ``mask`` (all if None): one kernel (the terms wrote the simulator's
        parameter tensors and its collision sizes directly); ``current_stream``: on Warp's current stream."""
        used = self.values
        if any(f in used for f in BODY_KEYS):
            self.sim.commit_mover_params(mask, scale_inertia="mover_mass" in used and "mover_inertia" not in used,
                                         current_stream=current_stream)

    def reset_in_step(self, mask: torch.Tensor) -> None:
        """:meth:`reset` inside an env step (the fused step, possibly being captured as a CUDA graph): the same draws
        and writes, the pack kernel on Warp's current stream. ``mask``: a device tensor (no host sync)."""
        self._fire("reset", mask)
        self.commit(mask, current_stream=True)
