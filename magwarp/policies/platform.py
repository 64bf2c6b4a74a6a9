"""Scripted baseline for :class:`magwarp.envs.platform_pose.PlatformPoseEnv`: a carrot in platform space plus the IK.

The policy keeps a carrot pose per env (set to the measured platform pose when an episode starts) and moves it
toward the goal by at most ``carrot_step`` per env step (x, y, z, roll, pitch, yaw; the yaw the short way round).
In ``action_mode="mover"`` the carrot is mapped through the IK to mover targets and tracked
(:func:`magwarp.magbots.control.track_movers`, with the carrot's rate and acceleration as feed-forward); in
``action_mode="pose"`` the carrot is the commanded target, sent as a pose increment. Moving the carrot in platform
space (not the movers straight to their goal positions) keeps the mover distance inside its limits while the
platform turns, so the movers never cross.

:class:`CarrotTracker` is that carrot for any env on the platform (the pick-and-place baseline drives it through
waypoints); ``carrot_change`` optionally limits how fast the carrot's step grows or shrinks per env step (an
acceleration limit, with braking before the waypoint), so a carried load does not slip.
"""

from __future__ import annotations

import torch

from magwarp.magbots.control import track_movers
from magwarp.magbots.kinematics import platform_ik, wrap_to_pi

__all__ = ["CarrotTracker", "PlatformIKPolicy", "limited_step"]


def _delta(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a - b`` for poses ``[..., 6]``, the yaw difference wrapped."""
    d = a - b
    return torch.cat([d[..., :5], wrap_to_pi(d[..., 5:])], -1)


def limited_step(delta: torch.Tensor, previous: torch.Tensor, max_step: torch.Tensor,
                 max_change: torch.Tensor | None = None) -> torch.Tensor:
    """A carrot's next step toward a goal ``delta`` away (per axis): at most ``max_step``; with ``max_change``, at
    most ``max_change`` longer than the ``previous`` step, and no longer than what still brakes to a stop at the goal
    with that change per step (``sqrt(2 c |delta|) + c / 2``)."""
    limit = max_step
    if max_change is not None:
        brake = torch.sqrt(2.0 * max_change * delta.abs()) + 0.5 * max_change
        limit = torch.minimum(torch.minimum(limit, previous.abs() + max_change), brake)
    return torch.maximum(torch.minimum(delta, limit), -limit)


def _six(values, name: str, device) -> torch.Tensor:
    t = torch.as_tensor(values, dtype=torch.float32, device=device)
    if t.shape != (6,) or not bool((t > 0).all()):
        raise ValueError(f"{name} must be six positive numbers, got {values!r}")
    return t


class CarrotTracker:
    """A carrot pose per world moved toward a goal pose ``[W, 6]`` each call, returned as the env's action.

    :param env: a :class:`~magwarp.envs.platform_pose.PlatformPoseEnv` (or a task built on it).
    :param carrot_step: largest carrot move per env step (x, y, z, roll, pitch, yaw).
    :param carrot_change: ``None`` (the carrot jumps to full speed) or the largest change of the carrot's step per
        env step, per axis; the carrot then also brakes so that it stops at the goal.
    """

    def __init__(self, env, carrot_step=(0.04, 0.04, 0.01, 0.03, 0.03, 0.08), carrot_change=None):
        self.env = env
        self.carrot_step = _six(carrot_step, "carrot_step", env.device)
        self.carrot_change = None if carrot_change is None else _six(carrot_change, "carrot_change", env.device)
        self.carrot = env.platform_pose().clone()
        self.step = torch.zeros(env.num_envs, 6, device=env.device)
        self.rate = torch.zeros(env.num_envs, 2, 3, device=env.device)
        self.high = torch.as_tensor(env.single_action_space.high, device=env.device)

    def __call__(self, goal: torch.Tensor, fresh: torch.Tensor) -> torch.Tensor:
        """The action that moves the carrot toward ``goal`` ``[W, 6]``; ``fresh`` ``[W]`` bool restarts the carrot
        at the platform's pose (pose mode: at the commanded target) in the worlds where an episode just began."""
        env = self.env
        fresh = fresh[:, None]
        start = env.target_pose if env.action_mode == "pose" else env.platform_pose()
        self.carrot = torch.where(fresh, start, self.carrot)
        step = limited_step(_delta(goal, self.carrot), torch.where(fresh, 0.0, self.step), self.carrot_step,
                            self.carrot_change)
        self.step = step
        previous = self.carrot
        self.carrot = previous + step
        if env.action_mode == "pose":
            return torch.clamp(_delta(self.carrot, env.target_pose) / env.pose_step, -1.0, 1.0)
        g = env.geometry
        movers = platform_ik(self.carrot, env.mover_z, g, check=False)[..., [0, 1, 3]]
        before = platform_ik(previous, env.mover_z, g, check=False)[..., [0, 1, 3]]
        period = env.backend.control.num_cycles * env.backend.dt
        rate = (movers - before) / period
        # the carrot's acceleration as feed-forward (the centripetal part keeps the spread while the platform turns)
        feed = (rate - torch.where(fresh[..., None], rate, self.rate)) / period
        self.rate = rate
        pos, vel = env.mover_state()
        act = (track_movers(pos, vel, movers, env.gains, target_vel=rate) + feed).reshape(env.num_envs, 6)
        return torch.maximum(torch.minimum(act, self.high), -self.high)


class PlatformIKPolicy:
    """``policy(obs=None) -> action [num_envs, 6]`` for a :class:`~magwarp.envs.platform_pose.PlatformPoseEnv`."""

    def __init__(self, env, carrot_step: tuple[float, ...] = (0.04, 0.04, 0.01, 0.03, 0.03, 0.08)):
        self.env = env
        self.tracker = CarrotTracker(env, carrot_step)

    def __call__(self, obs=None) -> torch.Tensor:
        return self.tracker(self.env.goal_pose, self.env.num_steps == 0)
