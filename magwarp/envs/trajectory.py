"""Long-horizon global trajectory planning (MagBotSim's ``LongHorizonGlobalTrajectoryPlanningEnv``), batched.

Every mover has a goal. Per env step (``num_cycles`` control cycles at 1 ms, the same action held):

* observation: x/y velocities of all movers (plus x/y accelerations when learning jerk), flattened mover by mover;
  achieved_goal: mover x/y positions; desired_goal: goal x/y positions;
* reward: ``reward_collision`` on a mover-mover or wall collision, else ``reward_success`` times the number of
  movers within ``threshold_pos`` of their goals, else ``reward_per_step``;
* terminated on collision (the world stops moving at the cycle of the collision, as MagBotSim's does);
* truncated when no goal was reached for more than ``timeout_steps`` steps, or (optional, off by default as in
  MagBotSim) after ``max_episode_steps`` steps;
* reached goals are resampled after the reward is computed, so the returned observation still shows the goal the
  reward was computed for (consistent for hindsight relabelling); the new goal appears from the next step on.

Sim2real options (:mod:`magwarp.envs.sim2real`): ``actuation=ActuationConfig(...)`` delays actions by ``k`` control
cycles per world (fixed or drawn at resets), ``sensors=SensorConfig(...)`` adds per-world bias, white noise and
dropped readings to the observed positions and velocities; ``num_cycles`` is the zero-order hold at the PLC's rate.

Differences from MagBotSim, on purpose: observations are float32 and noise-free unless ``std_noise`` > 0 (MagBotSim's
default adds 1e-5 to positions and velocities; ``std_noise=s`` is ``SensorConfig(pos_noise_std=s,
vel_noise_std=s)``); an action outside the action space
is not box-clipped (its norm is clipped by the mover's acceleration/jerk limit, the physical rule).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch

from magwarp._checks import as_count, warp_device
from magwarp.collision import CollisionQuery
from magwarp.envs.base import MagwarpVecEnv
from magwarp.envs.config import resolve_config
from magwarp.envs.episode import ChosenEpisodes, fmt_xy
from magwarp.envs.planar_randomization import SIZE_FIELDS, PlanarRandomizer
from magwarp.envs.sampling import PoseSampler
from magwarp.envs.sim2real import DrawClock, Latency, SensorModel
from magwarp.envs.step_graph import continued_generator
from magwarp.envs.trajectory_config import TrajectoryConfig
from magwarp.envs.trajectory_fused import FusedTrajectoryStep, fused_step_blocker
from magwarp.layout import Layout
from magwarp.sim import Simulator

__all__ = ["TrajectoryConfig", "TrajectoryPlanningEnv"]


class TrajectoryPlanningEnv(ChosenEpisodes, MagwarpVecEnv):
    """Batched trajectory planning: ``TrajectoryPlanningEnv(num_envs, layout, num_movers, *, config=None,
    device=None, seed=None, **options)``. The options (layout, collisions, limits, rewards, episode cuts, sim2real
    models, randomisation, the fused step) are the fields of :class:`~magwarp.envs.trajectory_config.TrajectoryConfig`,
    documented there, given as a ``config``, as keywords, or both (keywords on top). A configuration in which the
    movers cannot be placed raises a ``ValueError`` naming these values. The per-world state of the sim2real models
    is in ``env.sim.latency_cycles`` and ``env.sensors.pos_bias`` / ``vel_bias``.

    Chosen episodes (e.g. a MagBotSim episode replayed): ``reset(seed=..., options={...})`` with any of

    * ``"start_xy"``: mover start positions ``[M, 2]`` (every reset env) or ``[num_envs, M, 2]``;
    * ``"start_yaw"``: their headings ``[M]`` or ``[num_envs, M]`` (rad; with ``"start_xy"``; default 0);
    * ``"goals"``: the goals ``[M, 2]`` or ``[num_envs, M, 2]``;
    * ``"reset_mask"``: which envs to reset (``[num_envs]`` bool; default all).

    Starts must be on the tiles and collision free under the per-cycle rule (collision sizes, ``safety_margin``,
    ``collision_offset_wall``), goals on the tiles (a mover's footprint there, wall margin included); a value that is
    not raises a ``ValueError`` naming it, and nothing is reset. Keys not given are sampled as usual.

    The step (:mod:`magwarp.envs.trajectory_fused`): with ``fused=True`` (default) the task logic after the physics
    (observations, reward, terminations, goal resampling, NaN guard, autoreset) runs as two Warp kernels around the
    simulator's, and on CUDA with ``graph=True`` (default) the whole step is one captured CUDA graph, replayed with no
    host sync. Its results are the same as the torch step's (``fused=False``) for the same seed and actions, with the
    sensor models, action latency and randomisation terms on. Benchmark metrics, ``nan_dump`` and ``autoreset=False``
    take the torch step; :attr:`step_path` says which one runs. On the fused path the returned tensors are the env's
    buffers: valid through the next step, overwritten by the one after it (clone what you keep longer).
    """

    EPISODE_OPTIONS = {"start_xy": ("M", 2), "start_yaw": ("M",), "goals": ("M", 2)}

    #: benchmark metric tracker (:func:`magwarp.metrics.Metrics` attaches one); adds ``info["metrics"]``
    benchmark_metrics = None
    #: domain randomisation (``randomization``: event terms or a preset name, :mod:`magwarp.envs.planar_randomization`)
    randomizer = None

    #: the options' dataclass (:mod:`magwarp.envs.config`)
    config_type = TrajectoryConfig

    def __init__(self, num_envs: int = 1, layout: str | Layout | np.ndarray | None = None,
                 num_movers: int | None = None, *, config: TrajectoryConfig | None = None, device: str | None = None,
                 seed: int | None = None, render_mode: str | None = None, autoreset: bool = True,
                 check_inputs: bool = True, nan_dump: str | None = None, **options):
        """``TrajectoryPlanningEnv(num_envs, layout=None, num_movers=None, *, config=None, device=None, seed=None,
        ..., **options)``: the options (:class:`~magwarp.envs.trajectory_config.TrajectoryConfig`'s fields) are
        ``config`` (None: the defaults) with ``layout``, ``num_movers`` (positional, as MagBotSim's envs take them)
        and ``options`` applied on top; ``layout`` and ``num_movers`` None leave the config's."""
        if layout is not None:
            options["layout"] = layout
        if num_movers is not None:
            options["num_movers"] = num_movers
        cfg = resolve_config(type(self), config, options)
        self.config = cfg
        num_envs = as_count(num_envs, "num_envs")
        self.fused = cfg.fused
        self.sim = self._build_sim(cfg, num_envs, device)
        super().__init__(num_envs, self.sim.torch_device, seed=seed, render_mode=render_mode, autoreset=autoreset,
                         check_inputs=check_inputs, nan_dump=nan_dump)
        self._build_task(cfg, seed)
        self._build_spaces(cfg)
        self._fused_step = None
        self._graph = cfg.graph
        # before the first reset
        self.randomizer = PlanarRandomizer(self, cfg.randomization) if cfg.randomization else None
        self.reset()
        # The sampled starts must satisfy the per-cycle rule (walls and mover-mover with the safety margin). Starts are
        # sampled with the built sizes: collision sizes or margins drawn larger than those may make them collide (the
        # randomisation module's doc says to build with the largest size drawn), so the check is the built sizes' only.
        if self.randomizer is None or not any(f in SIZE_FIELDS for f in self.randomizer.values):
            self.sim._raise_on_start_collisions()

    # ------------------------------------------------------------------ construction parts
    def _build_sim(self, cfg: TrajectoryConfig, num_envs: int, device) -> Simulator:
        """The simulator of the config's layout, movers and limits (``layout``, ``layout_name``, ``num_movers``)."""
        layout_obj, _, self.layout_name = cfg.resolve_layout()
        self.layout = layout_obj
        self.num_movers = num_movers = cfg.movers
        radii, halves = cfg.collision_sizes()
        # The simulator is built with placeholder starts (every mover at the first tile centre) that are never
        # validated nor simulated: the first reset replaces them with sampled, collision-free starts, which are then
        # checked with the simulator's own rule. (Tile-centre defaults overlap once the collision size exceeds half a
        # tile, and need as many tiles as movers.)
        placeholder = np.repeat(layout_obj.tile_centers()[:1], num_movers, axis=0)
        return Simulator(
            layout_obj, num_movers, num_envs, mover=cfg.make_mover(),
            control="jerk" if cfg.learn_jerk else "acceleration", v_max=cfg.v_max, a_max=cfg.a_max, j_max=cfg.j_max,
            device=warp_device(device).alias, check_inputs=False, start_xy=placeholder, validate_starts=False,
            collision_radii=radii, collision_half_sizes=halves, force_model=cfg.force_model,
        )

    def _build_task(self, cfg: TrajectoryConfig, seed: int | None) -> None:
        """The task's options, its sensor and latency models, the start and goal sampler and the per-world task
        state."""
        self.learn_jerk = cfg.learn_jerk
        self.std_noise = float(cfg.std_noise)
        self.num_cycles = cfg.num_cycles
        #: the key and clock of the sensor and latency models' counter-based draws (they leave the generator alone)
        self.draw_clock = DrawClock(0 if seed is None else int(seed), self.device)
        self.sensors = SensorModel(cfg.sensor_config(), self.num_envs, self.num_movers, self.device, self.draw_clock)
        self.latency = Latency(cfg.actuation, self.sim, self.num_cycles, self.draw_clock)
        self.threshold_pos = float(cfg.threshold_pos)
        self.reward_success = float(cfg.reward_success)
        self.reward_collision = float(cfg.reward_collision)
        self.reward_per_step = float(cfg.reward_per_step)
        self.timeout_steps = cfg.timeout_steps
        self.max_episode_steps = None if cfg.max_episode_steps is None else int(cfg.max_episode_steps)
        # The pools are drawn with their own generator, seeded like the per-step one: reset(seed=s) redraws them from
        # s, so that the reset seed alone fixes a run (whatever seed the env was built with).
        self._pool_generator = torch.Generator(device=self.device)
        self._pool_generator.manual_seed(0 if seed is None else int(seed))
        self.sampler = PoseSampler(self.sim, cfg.collision_offset, self._pool_generator)
        self.sampler.generator = self._generator
        n, m = self.num_envs, self.num_movers
        self.goals = torch.zeros(n, m, 2, device=self.device)
        self.num_steps = torch.zeros(n, dtype=torch.int64, device=self.device)
        self.last_goal_step = torch.zeros(n, dtype=torch.int64, device=self.device)
        self.collected_goals = torch.zeros(n, m, dtype=torch.int64, device=self.device)

    def _build_spaces(self, cfg: TrajectoryConfig) -> None:
        """The observation (a goal-env dict) and action (per-mover acceleration or jerk, flat) spaces."""
        m = self.num_movers
        limit = cfg.j_max if cfg.learn_jerk else cfg.a_max
        ext = np.array(self.layout.extent * m, dtype=np.float32)
        obs_dim = m * 2 * (2 if cfg.learn_jerk else 1)
        self._set_spaces(
            gym.spaces.Dict({
                "observation": gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32),
                "achieved_goal": gym.spaces.Box(np.zeros_like(ext), ext, dtype=np.float32),
                "desired_goal": gym.spaces.Box(np.zeros_like(ext), ext, dtype=np.float32),
            }),
            gym.spaces.Box(-limit, limit, (m * 2,), np.float32),
        )

    # ------------------------------------------------------------------ task hooks
    def _reseed(self, seed: int) -> None:
        super()._reseed(seed)
        self.draw_clock.reseed(seed, self._step_count)
        self._pool_generator.manual_seed(seed)
        self.sampler.draw_pools(self._pool_generator)
        if self.randomizer is not None:
            self.randomizer.reseed(seed)

    def _nonfinite_worlds(self, obs) -> torch.Tensor:
        return (self.sim.nonfinite_step >= 0) | super()._nonfinite_worlds(obs)

    def state_arrays(self, worlds) -> dict[str, Any]:
        return {**super().state_arrays(worlds), **{f"sim_{k}": v for k, v in self.sim.state_arrays(worlds).items()},
                "goals": self.goals.cpu().numpy()[worlds]}

    def _reset_envs(self, mask: torch.Tensor) -> None:
        n = self.num_envs
        starts = self._chosen_or("start_xy", self.sampler.sample_starts(n))
        start_pos = self.sim.start_pos
        start_pos[..., :2] = torch.where(mask[:, None, None], starts, start_pos[..., :2])
        half_yaw = 0.5 * self._chosen_or("start_yaw", torch.zeros(n, self.num_movers, device=self.device))
        quat = torch.stack([torch.zeros_like(half_yaw), torch.zeros_like(half_yaw), half_yaw.sin(), half_yaw.cos()], -1)
        self.sim.start_quat.copy_(torch.where(mask[:, None, None], quat, self.sim.start_quat))
        self.sim.reset(mask)
        goals = self._chosen_or("goals", self.sampler.sample_goals(n, self.num_movers))
        self.goals.copy_(torch.where(mask[:, None, None], goals, self.goals))
        zero = torch.zeros_like(self.num_steps)
        self.num_steps.copy_(torch.where(mask, zero, self.num_steps))
        self.last_goal_step.copy_(torch.where(mask, zero, self.last_goal_step))
        self.collected_goals.masked_fill_(mask[:, None], 0)
        self.draw_clock.tick_reset()
        self.latency.reset(mask)
        self.sensors.reset(mask)
        if self.randomizer is not None:
            self.randomizer.reset(mask)
        if self.benchmark_metrics is not None:
            self.benchmark_metrics.episode_reset(mask)

    def _check_episode(self, chosen: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        if "start_yaw" in chosen and "start_xy" not in chosen:
            raise ValueError("options['start_yaw'] needs options['start_xy'] (sampled starts begin at yaw 0)")
        col = self.sim.model.collision
        if getattr(self, "_episode_query", None) is None:
            self._episode_query = CollisionQuery(self.layout, self.sim.mover.collision_shape,
                                                 offset_wall=col.wall_margin, device=str(self.sim.device))
        circle = self.sim.mover.collision_shape == "circle"
        size = torch.as_tensor(self.sim._radii_np if circle else self.sim._half_np, dtype=torch.float32,
                               device=self.device)
        n, m = self.num_envs, self.num_movers
        if "start_xy" in chosen:
            yaw = chosen.get("start_yaw", torch.zeros(n, m, device=self.device))
            poses = torch.cat([chosen["start_xy"], yaw[..., None]], -1)
            self._check_movers(self._episode_query, "start_xy", poses, size + col.margin, size, mask)
        if "goals" in chosen:
            goals = chosen["goals"]
            poses = torch.cat([goals, torch.zeros(n, m, 1, device=self.device)], -1)
            walls = self._episode_query(poses, size).wall_valid
            self._raise_first(~walls & mask[:, None], lambda i: (
                f"options['goals'] puts the goal of mover {i[1]} of env {i[0]} at {fmt_xy(goals[i[0], i[1]])}, where "
                "the mover would be off the tiles"))

    def _apply_action(self, action: torch.Tensor) -> None:
        self.sim.step(self.num_cycles, action.view(self.num_envs, self.num_movers, 2))
        self.sensors.new_step()

    def _get_obs(self) -> dict[str, torch.Tensor]:
        n = self.num_envs
        pos, obs = self.sensors.read(self.sim.pos[..., :2], self.sim.vel[..., :2])
        if self.learn_jerk:
            obs = torch.cat([obs, self.sim.acc.reshape(n, -1)], dim=1)
        return self.sensors.hold({
            "observation": obs.clone(),
            "achieved_goal": pos.clone(),
            "desired_goal": self.goals.reshape(n, -1).clone(),
        })

    def _replace_generator(self) -> None:
        """Give the env's draws (goals, starts) a new generator that continues from the old one
        (:func:`~magwarp.envs.step_graph.continued_generator`: a failed CUDA graph capture may leave the old one
        registered with the dead graph)."""
        self._generator = self.sampler.generator = continued_generator(self._generator)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """See :meth:`MagwarpVecEnv.reset`; the sensor model remembers the returned readings (for dropped ones)."""
        obs, info = super().reset(seed=seed, options=options)
        self.sensors.commit(obs)
        return obs, info

    @property
    def step_path(self) -> str:
        """Which step :meth:`step` runs now: ``"fused graph"`` (CUDA, one graph replay), ``"fused"`` (the same
        kernels, eager: CPU or ``graph=False``) or ``"eager (REASON)"`` (the torch step; see
        :func:`~magwarp.envs.trajectory_fused.fused_step_blocker`)."""
        reason = fused_step_blocker(self)
        if reason is not None:
            return f"eager ({reason})"
        return "fused graph" if self._graph and self.sim.device.is_cuda else "fused"

    def step(self, action):
        """See :meth:`MagwarpVecEnv.step`; the sensor model remembers the returned readings (for dropped ones).

        On the fused path (:attr:`step_path`) the returned tensors are the env's own buffers, valid through the next
        step and overwritten by the one after it (:mod:`magwarp.envs.trajectory_fused`)."""
        if fused_step_blocker(self) is None:
            action = self._check_action(action)
            with torch.inference_mode(False):  # its buffers are updated in place in and outside inference mode
                if self._fused_step is None:
                    self._fused_step = FusedTrajectoryStep(self, graph=self._graph)
                return self._fused_step.step(action)
        with self.draw_clock.step(self._step_count):
            out = super().step(action)
        self.sensors.commit(out[0])
        return out

    def _collisions(self) -> tuple[torch.Tensor, torch.Tensor]:
        flags = self.sim.flags_any
        return (flags & 1).any(dim=1), (flags & 2).any(dim=1)

    def _evaluate(self, obs):
        mover_collision, wall_collision = self._collisions()
        info = {
            "mover_collision": mover_collision,
            "wall_collision": wall_collision,
            "steps_since_goal": self.num_steps - self.last_goal_step,
        }
        reward = self.compute_reward(obs["achieved_goal"], obs["desired_goal"], info)
        terminated = mover_collision | wall_collision
        if self.timeout_steps is None:
            timed_out = torch.zeros_like(terminated)
        else:
            timed_out = info["steps_since_goal"] > self.timeout_steps
        info["collected_goals"] = self.collected_goals
        if self.benchmark_metrics is not None:
            # only a timeout fails the pending goals; the episode-length cut leaves them open
            info["metrics"] = self.benchmark_metrics.on_step(obs, info, terminated, timed_out)
        truncated = timed_out
        if self.max_episode_steps is not None:  # num_steps counts the steps before this one
            cut = self.num_steps + 1 >= self.max_episode_steps
            truncated = timed_out | cut
            # episodes cut by max_episode_steps alone: their pending goals are not lost (training's success counter)
            info["time_limit"] = cut & ~timed_out & ~terminated
        return reward, terminated, truncated, info

    def _end_step(self, obs, info) -> None:
        self.num_steps += 1
        reached = self.goal_distance(obs["achieved_goal"], obs["desired_goal"]) <= self.threshold_pos
        self.collected_goals += reached
        self.last_goal_step.copy_(torch.where(reached.any(dim=1), self.num_steps, self.last_goal_step))
        new_goals = self.sampler.sample_goals(self.num_envs, self.num_movers)
        self.goals.copy_(torch.where(reached[..., None], new_goals, self.goals))
        info["collected_goals"] = self.collected_goals.clone()
        info["goals_reached"] = reached

    def scripted_policy(self):
        """The built-in collision-aware goal-seeking planner for this env (a baseline: ``action = policy(obs)``)."""
        from magwarp.policies.planner import GoalSeekingPlanner

        return GoalSeekingPlanner(self)

    def _render_frame(self) -> torch.Tensor:
        if getattr(self, "_renderer", None) is None:
            from magwarp.render import TopDownRenderer

            worlds = getattr(self, "_render_worlds", None) or min(self.num_envs, 16)
            self._renderer = TopDownRenderer(self.layout, self.sim.mover, worlds=worlds, device=self.sim.device)
        sim = self.sim
        return self._renderer.draw(sim.pos, sim.quat, flags=sim.flags_any, radii=sim.radii, half_sizes=sim.half_sizes,
                                   goals=self.goals)

    # ------------------------------------------------------------------ reward (batched, for HER)
    def goal_distance(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor) -> torch.Tensor:
        """Per-mover distance ``(..., num_movers)`` between flattened x/y achieved and desired goals."""
        a = torch.as_tensor(achieved_goal).reshape(*achieved_goal.shape[:-1], self.num_movers, 2)
        d = torch.as_tensor(desired_goal).reshape(*desired_goal.shape[:-1], self.num_movers, 2)
        return (a - d).norm(dim=-1)

    def compute_reward(self, achieved_goal, desired_goal, info) -> torch.Tensor:
        """Reward for a batch ``(..., num_movers * 2)``; ``info`` holds ``mover_collision`` and ``wall_collision``
        (bool tensors of the batch shape) or may be ``None`` (no collisions)."""
        achieved_goal = torch.as_tensor(achieved_goal)
        desired_goal = torch.as_tensor(desired_goal, device=achieved_goal.device)
        batch = achieved_goal.shape[:-1]
        collision = torch.zeros(batch, dtype=torch.bool, device=achieved_goal.device)
        if info is not None:
            for key in ("mover_collision", "wall_collision"):
                if key in info:
                    flag = torch.as_tensor(info[key], device=achieved_goal.device).reshape(batch).bool()
                    collision = collision | flag
        reached = (self.goal_distance(achieved_goal, desired_goal) <= self.threshold_pos).sum(dim=-1)
        reward = torch.where(reached > 0, self.reward_success * reached.to(torch.float32),
                             torch.full(batch, self.reward_per_step, device=achieved_goal.device))
        return torch.where(collision, torch.full_like(reward, self.reward_collision), reward)
