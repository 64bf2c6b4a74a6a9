"""Scripted baseline for :class:`magwarp.envs.gripper_pick_place.GripperPickPlaceEnv`: waypoints of the jaw.

The policy keeps a carrot gripper state per world in *jaw* coordinates: the jaw centre's x, y, the gripper's yaw and
the jaw width. Mover A sits ``grip_offset`` ahead of the jaw centre along the yaw, mover B the width's mover distance
further on (:meth:`GripperPickPlaceEnv.mover_targets`), so turning the carrot turns the gripper about its jaw and a
held object does not swing. The carrot moves toward each phase's waypoint with a speed and acceleration limit
(:func:`magwarp.policies.platform.limited_step`); the movers track it with feed-forward (``action_mode="mover"``) or
it is sent as increments of the commanded state (``"gripper"``). Phases (batched state machine):

0. pre-grasp: the open jaw ``pregrasp`` in front of the object, the gripper square to one of the object's faces, the
   one facing the layout's centre most (so mover B stays on the tiles);
1. advance: the open jaw over the object;
2. close: the width below the object's by ``squeeze`` until the jaw holds it;
3. carry: the object (not the jaw: the object's offset in the jaw is corrected) to the goal, the gripper turning to
   point from the goal toward the centre; the object within ``release_at`` of the goal ends it;
4. release: open the jaw where the carrot is.

A world whose object leaves the jaw while carrying starts again at 0.
"""

from __future__ import annotations

import math

import torch

from magwarp.magbots.control import track_movers
from magwarp.policies.platform import limited_step

__all__ = ["GripperPickPlacePolicy"]

PREGRASP, ADVANCE, CLOSE, CARRY, RELEASE = range(5)


def _wrap(a: torch.Tensor) -> torch.Tensor:
    return torch.remainder(a + math.pi, 2 * math.pi) - math.pi


class GripperPickPlacePolicy:
    """``policy(obs=None) -> action [num_envs, 4]`` for a :class:`GripperPickPlaceEnv` (either action mode)."""

    def __init__(self, env, *, pregrasp: float = 0.08, squeeze: float = 0.02, tolerance: float = 0.005,
                 release_at: float = 0.008,
                 carrot_step=(0.01, 0.01, 0.06, 0.006), carrot_change=(0.0015, 0.0015, 0.01, 0.002)):
        self.env = env
        dev = env.device
        self.pregrasp, self.squeeze, self.tolerance = float(pregrasp), float(squeeze), float(tolerance)
        self.release_at = float(release_at)
        self.max_step = torch.as_tensor(carrot_step, dtype=torch.float32, device=dev)
        self.max_change = torch.as_tensor(carrot_change, dtype=torch.float32, device=dev)
        for name, t in (("carrot_step", self.max_step), ("carrot_change", self.max_change)):
            if t.shape != (4,) or not bool((t > 0).all()):
                raise ValueError(f"{name} must be four positive numbers (x, y, yaw, width), got {t.tolist()}")
        n = env.num_envs
        self.phase = torch.zeros(n, dtype=torch.int64, device=dev)
        self.carrot = torch.zeros(n, 4, device=dev)
        self.step = torch.zeros(n, 4, device=dev)
        self.rate = torch.zeros(n, 2, 2, device=dev)
        self.held = torch.zeros(n, dtype=torch.int64, device=dev)
        self.last_width = torch.zeros(n, device=dev)
        self.grasp_yaw = torch.zeros(n, device=dev)
        self.restart = torch.ones(n, dtype=torch.bool, device=dev)  # a grasp starts at the next call
        self.centre = 0.5 * torch.as_tensor(env.layout.extent, dtype=torch.float32, device=dev)
        self.high = torch.as_tensor(env.single_action_space.high, device=dev)
        self.open = env._width_high - 0.01

    def _jaw_state(self) -> torch.Tensor:
        """The measured state in jaw coordinates ``[W, 4]`` (jaw x, y, yaw, width)."""
        s = self.env.gripper_state()
        return torch.cat([self.env.jaw_centre(s), s[:, 2:]], 1)

    def _mover_state(self, jaw: torch.Tensor) -> torch.Tensor:
        """Jaw coordinates -> the env's gripper states (mover A's x, y, yaw, width)."""
        u = torch.stack([torch.cos(jaw[:, 2]), torch.sin(jaw[:, 2])], -1)
        return torch.cat([jaw[:, :2] + self.env.grip_offset * u, jaw[:, 2:]], 1)

    def _heading(self, p: torch.Tensor, fallback: torch.Tensor) -> torch.Tensor:
        """Yaw pointing from ``p`` ``[W, 2]`` toward the layout's centre (``fallback`` where ``p`` is the centre)."""
        d = self.centre - p
        return torch.where(d.norm(dim=-1) > 0.02, torch.atan2(d[:, 1], d[:, 0]), fallback)

    def _fits(self, jaw: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
        """``[W]`` bool: with the jaw at ``jaw`` ``[W, 2]`` and the gripper at ``yaw``, both (open) movers stay
        ``margin`` inside the layout."""
        env = self.env
        margin = env.mover.bounding_radius(env.mover.wall_margin) + 0.03
        u = torch.stack([torch.cos(yaw), torch.sin(yaw)], -1)
        ext = 2 * self.centre
        ok = torch.ones_like(yaw, dtype=torch.bool)
        for reach in (env.grip_offset, env.grip_offset + env.geometry.max_distance):
            p = jaw + reach * u
            ok = ok & ((p >= margin) & (p <= ext - margin)).all(-1)
        return ok

    def __call__(self, obs=None) -> torch.Tensor:
        env = self.env
        fresh = env.num_steps == 0
        now = self._jaw_state()
        self.phase.masked_fill_(fresh, PREGRASP)
        self.carrot = torch.where(fresh[:, None], now, self.carrot)
        self.held.masked_fill_(fresh, 0)
        obj, obj_yaw, _ = env.object_state()
        in_jaw = (obj - now[:, :2]).norm(dim=-1)
        # grasp the box square to its faces: the face normal (object yaw + k pi/2) nearest the heading to the centre
        # (chosen when a grasp starts, and kept through it)
        # among the faces whose grasp keeps both movers on the tiles (also at the pre-grasp point)
        heading = self._heading(obj, now[:, 2])
        faces = obj_yaw[:, None] + 0.5 * math.pi * torch.arange(4, device=obj.device)
        cost = _wrap(faces - heading[:, None]).abs()
        for k in range(4):
            u_k = torch.stack([torch.cos(faces[:, k]), torch.sin(faces[:, k])], -1)
            fits = self._fits(obj, faces[:, k]) & self._fits(obj + self.pregrasp * u_k, faces[:, k])
            cost[:, k] = cost[:, k] + 10.0 * (~fits).float()
        face = faces.gather(1, cost.argmin(1, keepdim=True))[:, 0]
        self.grasp_yaw = torch.where(fresh | self.restart, face, self.grasp_yaw)
        yaw_obj = self.grasp_yaw
        # carry with the grasp's yaw when the movers fit around the goal with it, else turn toward the centre
        yaw_goal = torch.where(self._fits(env.goal, self.grasp_yaw), self.grasp_yaw,
                               self._heading(env.goal, now[:, 2]))
        u = torch.stack([torch.cos(yaw_obj), torch.sin(yaw_obj)], -1)
        grip = env.object_width - self.squeeze
        # waypoints [W, 5, 4] in jaw coordinates
        ways = torch.stack([
            torch.cat([obj + self.pregrasp * u, yaw_obj[:, None], torch.full_like(yaw_obj, self.open)[:, None]], 1),
            torch.cat([obj, yaw_obj[:, None], torch.full_like(yaw_obj, self.open)[:, None]], 1),
            torch.cat([obj, yaw_obj[:, None], torch.full_like(yaw_obj, grip)[:, None]], 1),
            torch.cat([env.goal + (now[:, :2] - obj), yaw_goal[:, None], torch.full_like(yaw_obj, grip)[:, None]], 1),
            torch.cat([self.carrot[:, :3], torch.full_like(yaw_obj, self.open)[:, None]], 1),
        ], 1)
        pick = lambda phase: ways.gather(1, phase[:, None, None].expand(-1, 1, 4))[:, 0]  # noqa: E731
        goal = pick(self.phase)
        err = goal - now
        pos_err, yaw_err = err[:, :2].norm(dim=-1), _wrap(err[:, 2]).abs()
        # held: the jaw has closed on the object (its width stalls near the object's)
        stalled = (now[:, 3] - self.last_width).abs() < 5e-4
        self.last_width = now[:, 3]
        self.held = torch.where((self.phase == CLOSE) & stalled & (now[:, 3] < env.object_width + 0.01),
                                self.held + 1, 0)
        nxt = self.phase.clone()
        nxt = torch.where((self.phase == PREGRASP) & (pos_err < 2 * self.tolerance) & (yaw_err < 0.05), ADVANCE, nxt)
        nxt = torch.where((self.phase == ADVANCE) & (pos_err < self.tolerance) & (yaw_err < 0.05), CLOSE, nxt)
        nxt = torch.where((self.phase == CLOSE) & (self.held >= 3), CARRY, nxt)
        there = ((obj - env.goal).norm(dim=-1) < self.release_at) & (yaw_err < 0.05)
        nxt = torch.where((self.phase == CARRY) & there, RELEASE, nxt)
        lost = (self.phase == CARRY) & (in_jaw > 0.03)
        nxt = torch.where(lost, PREGRASP, nxt)
        self.restart = lost
        self.phase = nxt
        goal = pick(nxt)
        delta = goal - self.carrot
        delta = torch.cat([delta[:, :2], _wrap(delta[:, 2:3]), delta[:, 3:]], 1)
        step = limited_step(delta, torch.where(fresh[:, None], 0.0, self.step), self.max_step, self.max_change)
        self.step = step
        previous = self.carrot
        self.carrot = previous + step
        self.carrot[:, 3] = self.carrot[:, 3].clamp(env._width_low, env._width_high)
        target = self._mover_state(self.carrot)
        if env.action_mode == "gripper":
            d = target - env.target
            d = torch.cat([d[:, :2], _wrap(d[:, 2:3]), d[:, 3:]], 1)
            return torch.clamp(d / env.gripper_step, -1.0, 1.0)
        movers = env.mover_targets(target)
        before = env.mover_targets(self._mover_state(previous))
        period = env.backend.control.num_cycles * env.backend.dt
        rate = (movers - before) / period
        feed = (rate - torch.where(fresh[:, None, None], rate, self.rate)) / period
        self.rate = rate
        pos, vel = env.mover_state()
        pad = torch.zeros_like(pos[..., :1])
        acc = track_movers(torch.cat([pos, pad], -1), torch.cat([vel, pad], -1), torch.cat([movers, pad], -1),
                           env.gains, target_vel=torch.cat([rate, pad], -1))[..., :2] + feed
        acc = acc + env.squeeze_accel(self.carrot[:, 3], env.gripper_state())
        act = acc.reshape(env.num_envs, 4)
        return torch.maximum(torch.minimum(act, self.high), -self.high)
