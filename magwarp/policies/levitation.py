"""The scripted baseline of the levitation envs (``magwarp/Levitation-v0`` and its variants): a PD law on the 6-DoF
pose through the commutation.

Wanted wrench (world frame): ``F = m (g e_z + a* + kp (p* - p) + kd (v* - v))`` and ``tau = I (alpha* - kr e + dr
(omega* - omega))`` with ``e`` the rotation error (world frame: the rotation vector from the reference attitude to
the mover's; roll and pitch errors read about the world axes would push a mover turned by 180 degrees the wrong
way), both
critically damped at the natural frequency ``frequency`` (Hz), the feedback accelerations clipped at ``max_acc``
(m/s^2 for x/y together and for z, rad/s^2 for the angular: a wanted wrench beyond what the coils under the mover
can deliver comes out distorted by the commutation's current limits, torques included, and tilts the mover);
``v*``, ``a*`` (and the angular ones) are the reference's rates where the observation has them (``task="track"``),
else 0. The commutation
(:meth:`magwarp.magnetics.actuator.CoilActuator.commutate`: least copper loss within the current limits, at the
mover's current pose) turns the wrench into the action's coil currents (or, with ``action="wrench"``, the wrench
itself is the action). Per task, from the observation:

* ``move``: x, y and yaw follow the least-acceleration (cubic) path to the goal that arrives at rest when the time
  left runs out, re-planned every step: gains ``kp = 6 / T^2``, ``kd = 4 / T`` for the time left ``T`` (the cubic's
  initial acceleration), capped at the PD's own (which take over at the deadline);
* ``payload``: the payload's weight and its torque about the mover centre are fed forward (mass ``m`` is the
  mover's plus the payload's);
* ``pendulum``: the rod's pull on the mover (tension ``m_b (|d'|^2 / L - g e_z)`` along the rod, from the swing
  angles and rates, and its torque about the centre) is cancelled.
"""

from __future__ import annotations

import math

import torch

from magwarp._vectors import clip_norm
from magwarp.pendulum import rotate

__all__ = ["DEFAULT_MAX_ACC", "LevitationPD"]

#: the shipped baseline's feedback acceleration limits (m/s^2 for x/y together and for z, rad/s^2 angular)
DEFAULT_MAX_ACC = (5.0, 60.0)


def _quat_from_rpy(rpy: torch.Tensor) -> torch.Tensor:
    """Quaternions (x, y, z, w) ``[N, 4]`` of roll, pitch, yaw ``[N, 3]`` (R = Rz(yaw) Ry(pitch) Rx(roll))."""
    h = 0.5 * rpy
    cr, sr, cp, sp, cy, sy = torch.cos(h[:, 0]), torch.sin(h[:, 0]), torch.cos(h[:, 1]), torch.sin(h[:, 1]), \
        torch.cos(h[:, 2]), torch.sin(h[:, 2])
    return torch.stack([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
                        cr * cp * cy + sr * sp * sy], -1)


def _quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    ax, ay, az, aw = a.unbind(-1)
    bx, by, bz, bw = b.unbind(-1)
    return torch.stack([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz], -1)


def _rotation_error(rpy: torch.Tensor, ref_rpy: torch.Tensor) -> torch.Tensor:
    """The rotation vector ``[N, 3]`` (world frame) that turns the reference attitude into the mover's."""
    q_ref = _quat_from_rpy(ref_rpy)
    q = _quat_mul(_quat_from_rpy(rpy), torch.cat([-q_ref[:, :3], q_ref[:, 3:]], 1))  # times the conjugate
    q = torch.where(q[:, 3:4] < 0, -q, q)  # the short way round
    v = q[:, :3]
    s = torch.linalg.vector_norm(v, dim=1, keepdim=True)
    angle = 2 * torch.atan2(s, q[:, 3:4])
    return v * torch.where(s > 1e-12, angle / s.clamp_min(1e-12), torch.full_like(s, 2.0))


def _yaw_to_world(yaw: torch.Tensor):
    """Roll, pitch and yaw rates ``[N, 3]`` as world angular rates at small tilts (roll and pitch about the axes
    turned by ``yaw``)."""
    c, s = torch.cos(yaw), torch.sin(yaw)

    def turn(rates: torch.Tensor) -> torch.Tensor:
        return torch.stack([c * rates[:, 0] - s * rates[:, 1], s * rates[:, 0] + c * rates[:, 1], rates[:, 2]], 1)

    return turn


class LevitationPD:
    """``policy(obs) -> action`` for a :class:`~magwarp.envs.levitation.LevitationEnv` (batched, on its device)."""

    def __init__(self, env, frequency: float = 15.0, damping: float = 1.0,
                 max_acc: tuple[float, float] = DEFAULT_MAX_ACC):
        self.env = getattr(env, "unwrapped", env)
        try:
            max_acc = tuple(float(v) for v in max_acc)
        except (TypeError, ValueError):
            max_acc = (float("nan"),)
        for name, value in (("frequency", frequency), ("damping", damping), *zip(("max_acc", "max_acc"), max_acc)):
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0 or len(max_acc) != 2:
                raise ValueError(f"{name} must be a positive finite number (max_acc: two), got "
                                 f"{max_acc if name == 'max_acc' else value!r}")
        self.max_lin, self.max_ang = self.max_acc = max_acc
        w = 2 * math.pi * frequency
        self.kp, self.kd = w * w, 2 * damping * w
        dev = self.env.device
        self.mass = float(self.env.mover.mass)
        self.inertia = torch.tensor(self.env.mover.inertia, dtype=torch.float32, device=dev)
        self.gravity = float(self.env.sim.model.limits.gravity)
        self.slices = self.env.obs_slices
        swing = getattr(self.env.task_terms, "swing", None)
        self._pivot = None if swing is None else torch.tensor(swing.pivot, dtype=torch.float32, device=dev)

    def _part(self, obs: torch.Tensor, name: str) -> torch.Tensor | None:
        s = self.slices.get(name)
        return None if s is None else obs[:, s]

    def _gains(self, obs: torch.Tensor) -> tuple[torch.Tensor | float, torch.Tensor | float]:
        """``kp``, ``kd``: ``[N, 6]`` (x, y, z, roll, pitch, yaw) with a time left (``move``), else numbers."""
        left = self._part(obs, "time_left")
        if left is None:
            return self.kp, self.kd
        t = left.clamp_min(1e-6)
        kp = torch.where(left > 0, torch.clamp(6.0 / (t * t), max=self.kp), torch.full_like(t, self.kp))
        kd = torch.where(left > 0, torch.clamp(4.0 / t, max=self.kd), torch.full_like(t, self.kd))
        full_p, full_d = torch.full_like(t, self.kp), torch.full_like(t, self.kd)
        return (torch.cat([kp, kp, full_p, full_p, full_p, kp], 1), torch.cat([kd, kd, full_d, full_d, full_d, kd], 1))

    def wrench(self, obs: torch.Tensor) -> torch.Tensor:
        """The PD law's wanted wrench ``[N, 6]`` for observations ``[N, D]``."""
        part = self._part
        pos, rpy, vel, omega, ref = part(obs, "pos"), part(obs, "rpy"), part(obs, "vel"), part(obs, "omega"), \
            part(obs, "reference")
        tilt = part(obs, "reference_tilt")
        ref_rp = torch.zeros_like(rpy[:, :2]) if tilt is None else tilt
        ref_vel, ref_acc = part(obs, "reference_vel"), part(obs, "reference_acc")
        zero6 = torch.zeros_like(obs[:, :6])
        ref_vel = zero6 if ref_vel is None else ref_vel
        ref_acc = zero6 if ref_acc is None else ref_acc
        kp, kd = self._gains(obs)
        kp = kp if isinstance(kp, torch.Tensor) else torch.full_like(zero6, kp)
        kd = kd if isinstance(kd, torch.Tensor) else torch.full_like(zero6, kd)
        payload = part(obs, "payload_mass")
        mass = self.mass if payload is None else self.mass + payload
        lin = ref_acc[:, :3] + kp[:, :3] * (ref[:, :3] - pos) + kd[:, :3] * (ref_vel[:, :3] - vel)
        lin = torch.cat([clip_norm(lin[:, :2], self.max_lin), lin[:, 2:].clamp(-self.max_lin, self.max_lin)], 1)
        force = mass * lin
        force[:, 2] += (mass * self.gravity).reshape(-1) if payload is not None else self.mass * self.gravity
        ref_rpy = torch.cat([ref_rp, ref[:, 3:4]], 1)
        err = _rotation_error(rpy, ref_rpy)
        turn = _yaw_to_world(ref[:, 3])
        torque = self.inertia * clip_norm(turn(ref_acc[:, 3:]) - kp[:, 3:] * err + kd[:, 3:] * (turn(ref_vel[:, 3:])
                                                                                                 - omega), self.max_ang)
        if payload is not None:  # the payload's weight acts at the centre of mass, off the mover centre
            com = part(obs, "payload_offset") * (payload / mass)
            weight = torch.zeros_like(com)
            weight[:, 2] = (mass * self.gravity).reshape(-1)
            torque = torque + torch.cross(rotate(_quat_from_rpy(rpy), com), weight, dim=-1)
        angle = part(obs, "swing_angle")
        if angle is not None:
            f_rod, t_rod = self._rod_wrench(rpy, angle, part(obs, "swing_rate"))
            force, torque = force - f_rod, torque - t_rod
        return torch.cat([force, torque], 1)

    def _rod_wrench(self, rpy, angle, rate) -> tuple[torch.Tensor, torch.Tensor]:
        """The swinging payload's pull on the mover (force, torque about the centre) from its swing angles and
        rates, with the pivot held still: tension ``m_b (|d'|^2 / L - g e_z)`` along the rod."""
        swing = self.env.task_terms.swing
        mass, length = swing.mass[:, None], swing.length[:, None]
        tan, sec2 = torch.tan(angle), 1.0 / torch.cos(angle) ** 2
        s = torch.cat([tan, -torch.ones_like(tan[:, :1])], 1)  # along the rod
        s_dot = torch.cat([rate * sec2, torch.zeros_like(tan[:, :1])], 1)
        norm = torch.linalg.vector_norm(s, dim=1, keepdim=True)
        e = s / norm
        e_dot = s_dot / norm - s * (s * s_dot).sum(1, keepdim=True) / norm ** 3
        tension = mass * (length * (e_dot * e_dot).sum(1, keepdim=True) - self.gravity * e[:, 2:3])
        f_rod = tension * e
        return f_rod, torch.cross(rotate(_quat_from_rpy(rpy), self._pivot.expand_as(f_rod)), f_rod, dim=-1)

    def __call__(self, obs: torch.Tensor) -> torch.Tensor:
        env = self.env
        wrench = self.wrench(obs)
        if env.action_mode == "wrench":
            return torch.clamp(wrench / env._scale, -1.0, 1.0)
        currents = env.actuator.commutate(wrench[:, None, :])[:, 0]
        return (currents / env.current_limit).to(torch.float32)
