"""The swarm env: many movers per world, each with its own goal stream, reward and collisions.

Per env step (``num_cycles`` control cycles at 1 ms, each mover's x/y command held):

* action ``[num_envs, num_movers, 2]``: x/y acceleration (or jerk, ``learn_jerk``) per mover, norm-clipped by the
  mover's limit (the physical rule), as in trajectory planning;
* observation ``[num_envs, num_movers, D]`` per mover: its x/y velocity (2), its goal relative to it (2), its x/y
  acceleration (2, jerk mode only), then its local view (:class:`~magwarp.swarm.LocalObservations`): the ``k``
  nearest movers within ``obs_radius`` (relative position, relative velocity, mask: 5 per slot) and the distances to
  the walls along ``num_rays`` rays. Per-mover work is O(k), not O(movers);
* per-mover reward (``info["agent_reward"]``): ``reward_collision`` if the mover collided (with a mover or a wall)
  during the step, else ``reward_goal`` if it is within ``threshold_pos`` of its goal at the end of the step, else
  ``reward_per_step``. The returned ``reward`` ``[num_envs]`` is their sum over the world's movers. A dense,
  potential-based progress term (``reward_progress``, per metre; default 0: off, the rewards bit for bit the sparse
  ones) adds ``reward_progress * (d_before - d_after)`` to ``reward_per_step``: ``d_before`` is the mover's distance
  to its goal at the step's start (from its position then), ``d_after`` the distance to that same goal at the step's
  end, so new goals and respawns placed at a step's end count as no progress (each mover's ``d_before`` is refreshed
  after them and at every reset, one small kernel, :func:`~magwarp.kernels.swarm.goal_distances`, inside the step's
  graph);
* goal streams: a mover that reaches its goal gets a new one at once (after the reward), placed clear of the other
  movers' goals (every goal set is a collision-free configuration, so all goals can be held at once);
* collisions (``on_collision``):

  - ``"respawn"`` (default): the movers involved stop at the cycle of the collision while the rest of the world goes
    on (a cycle hook, inside the step graph); after the step they are penalised, flagged in
    ``info["agent_terminated"]`` and re-placed at free spots (their agent episode restarts, their goal is kept). A
    mover that finds no free spot in ``respawn_rounds`` rounds stays stopped where it is and tries again each step
    (``info["respawn_pending"]``; no reward meanwhile);
  - ``"end"``: MagBotSim's rule: the world stops at the cycle of its first collision and its episode terminates;

* material flow (``stations``): goals are pick-up and drop-off stations in turn; each delivery completes a job
  (``info["job_done"]``, ``info["jobs"]``; the observation gains a carrying flag). Many movers may head for one
  station: queues form as on a real line;
* ``info["collided"]``: the movers that collided during the step (mover or wall; not those waiting to respawn);
  with a tracker attached (``magwarp.metrics.Metrics(env)``, as ``magwarp eval`` does) ``info["metrics"]`` holds
  its per-world counters;
* rendering (``render_mode="rgb_array"``): the whole world or a window of it, movers coloured by state, legible at
  thousands of movers (:meth:`SwarmEnv.set_render_view`, :mod:`magwarp.render.swarm`);
* shield (``shield=True``; safe RL): each step passes every mover's action through the planner's provably
  collision-free safety filter (:class:`~magwarp.swarm.SafetyFilter`, built as
  :class:`~magwarp.swarm.SwarmPlanner` builds it: :func:`~magwarp.swarm.safety.build_safety`) before the simulator
  sees it: the acceleration (norm-clipped at ``a_max``) becomes the velocity it reaches after one step, the filter
  replaces it by the safe velocity nearest to it (its own ``k`` = 24 nearest movers within its reach radius, and the
  cells off the tiles), and that velocity becomes the acceleration that reaches it within the step (at most
  ``a_max``), as the planner's last step does. An action whose velocity the filter keeps passes unchanged, bit for
  bit. Every mover then stays collision-free (with movers, holes and edges) whatever the policy asks, so training
  only has to learn throughput. The filter's options are the planner's defaults: speed cap ``shield_speed`` (1.5
  m/s, the planner's ``cruise``; movers go no faster), committed braking 0.95 ``a_max``, margin 0.002 m, 24
  neighbour slots. ``info["shield_active"]`` (bool ``[N, M]``) flags the movers whose action the shield changed,
  ``info["shield_delta"]`` (``[N, M]``, m/s^2) the norm of the change (against the action clipped at ``a_max``);
  both are false / 0 for stopped movers (pending respawns). Acceleration control only (``learn_jerk=False``); the
  filter models the plain planar dynamics (no actuator, latency or randomised limits set on the simulator later).
  All torch operations and Warp launches on the device: it runs inside the step's CUDA graph;
* truncation: after ``max_episode_steps`` steps (default None: worlds run on; goals stream, collided movers respawn).

Starts and goals are drawn by :class:`~magwarp.swarm.Placer` on the device (O(movers)). ``reset()`` checks that
every mover was placed (one host synchronisation) and raises :class:`~magwarp.swarm.PlacementError` with the
density asked and the density possible otherwise; resets inside ``step`` (autoreset) run a fixed number of rounds
without synchronising, and a mover left unplaced there waits as a pending respawn.

With the respawn rule and up to 256 movers per world (the training regime), the step's control cycles and collision
stops run as one launch (``fused``, :mod:`magwarp.swarm.fused`: one thread block per world on CUDA), with the
per-cycle path's results bit for bit; larger worlds, MagBotSim's rule and further cycle hooks run per cycle.
The rest of a step is a few launches over the movers, none of them a host sync: the command (stopped movers
zeroed; the env's device step count), one kernel for every mover's outcome (flags, reward, goal and job counts, what
it asks of the placers, :func:`~magwarp.kernels.swarm.evaluate_movers`), the goal and respawn placers (a thread per
mover to place in their rounds, each candidate checked against its world's movers: no cell lists up to 256 movers
per world on CUDA), one kernel that applies the respawns, the observation (one kernel writing each row straight into
the returned tensor, flagging non-finite rows; each mover scans its world's movers, on CUDA a thread block per world
with its movers in shared memory; above 256 movers per world, 128 on the CPU, grid binning first) and one kernel per
world for its reward, flags and NaN guard (:func:`~magwarp.kernels.swarm.finish_worlds`).

The whole step as one CUDA graph (``graph=True``, the default, on CUDA): after the host's input check and the copy of
the action into a fixed buffer, the step above (physics, task work, respawns, observation, autoreset) is replayed as
one captured graph (:func:`~magwarp.envs.step_graph.record_cuda_graph`, as the trajectory env's step), with no host
sync and no Python beyond the replay. Everything a step used to take from the host comes from the device: the
placers' seeds and round numbers (their device counters), the env's step count (the NaN guard's step), and the
stations' draws come from the env's torch generator, registered with the graph (each replay draws fresh numbers).
The first step of each of two graphs runs eagerly (it loads the kernels) and the graph is recorded after it; the two
graphs alternate, so the tensors a step returns are the graph's own outputs: valid through the next step,
overwritten by the one after it (clone what you keep longer). :attr:`SwarmEnv.step_path` says which path runs;
``graph=False``, the CPU, benchmark metrics and hooks replaced on the instance run the same launches eagerly, with
the same results bit for bit (fresh tensors each step). The random streams are the ones the host counters gave
before, so the eager step's results are unchanged, but for the world's reward, now summed in mover order by
``finish_worlds`` (torch's sum before): the same for the default rewards (integers), within float32 rounding for
others.

Every option is a field of :class:`SwarmConfig`; the constructor takes a config and/or the same names as keywords.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import torch
import warp as wp

from magwarp._checks import as_count, as_flag, warp_device
from magwarp._vectors import clip_norm
from magwarp.envs.base import MagwarpVecEnv
from magwarp.envs.config import make_mover_spec, resolve_config
from magwarp.envs.step_graph import RecordedGraph, continued_generator, record_cuda_graph
from magwarp.kernels.swarm import (SwarmRewards, apply_respawns, command_unless_stopped, evaluate_movers,
                                   finish_worlds, goal_distances, stop_collided)
from magwarp.layout import Layout, MoverSpec, benchmark_layout
from magwarp.sim import Simulator
from magwarp.swarm.fused import FusedSwarmStep, exchange, fused_applies, guard_in_step, launch_block
from magwarp.swarm.observations import LocalObservations, check_view_sizes
from magwarp.swarm.placement import Placer, on_torch_stream
from magwarp.swarm.safety import SAFE_SPEED, build_safety

__all__ = ["SwarmConfig", "SwarmEnv", "COLLISION_MODES"]

COLLISION_MODES = ("respawn", "end")
#: the most placement rounds of each kind a step runs (each is a launch of every step)
MAX_ROUNDS = 256
#: the step's hooks: one replaced on the instance (e.g. a benchmark timing each phase) makes the step run eagerly
STEP_HOOKS = ("_apply_action", "_evaluate", "_end_step", "_get_obs", "_finish", "_reset_envs", "_respawn")


class _StepGraph(NamedTuple):
    """One recorded env step: the graph (:class:`~magwarp.envs.step_graph.RecordedGraph`: its outputs are the step's
    returns) and the local observation's views of its observation tensor (``rel_pos``, ``rel_vel``, ``walls``)."""

    recorded: RecordedGraph
    views: tuple


@dataclass(frozen=True)
class SwarmConfig:
    """Options of :class:`SwarmEnv`. ``layout``: a :class:`Layout`, a 0/1 array, a benchmark name (``"B0"``..``"B9"``:
    its tiles; ``num_movers`` stays this config's), or None for a square grid of full tiles with about ``occupancy``
    movers per tile. Collision options as in trajectory planning: ``collision_shape``
    ``"circle"``/``"box"``, ``collision_size`` (radius or half sizes), ``safety_margin`` (grows every shape in the
    per-cycle check), ``collision_offset`` (extra room kept when placing starts and goals),
    ``collision_offset_wall`` (wall margin). ``k``, ``obs_radius``, ``num_rays``, ``ray_range``: the local view.
    ``respawn_rounds`` / ``goal_rounds`` / ``reset_rounds``: placement rounds run inside a step (no host sync).
    ``respawn_clearance``: extra room (m) a respawned mover keeps from the others and the walls (it appears next to
    moving movers: at the bare exclusion distance it would often be hit at once).
    ``stations``: the material-flow variant: ``"auto"`` (``num_stations`` pick-ups and drop-offs placed on the
    layout) or ``{"pickup": (P, 2), "dropoff": (D, 2)}`` positions; None: free goals (goal streams).
    ``fused``: run each step's control cycles and collision stops as one launch (:mod:`magwarp.swarm.fused`; the
    per-cycle path's results): None (default) where it applies (the respawn rule, up to 256 movers per world), True
    to insist (an error where it does not apply), False for the per-cycle path. ``graph``: on CUDA, record the whole
    env step as one CUDA graph and replay it (the module docstring); False: the same launches, eagerly.
    ``shield``: pass each action through the planner's safety filter (the module docstring; acceleration control
    only), with the speed cap ``shield_speed`` (m/s, at most ``v_max``; the planner's default cruise).
    Rewards (finite numbers): ``reward_collision``, ``reward_goal``, ``reward_per_step`` (the module docstring) and
    ``reward_progress``, the dense progress term: reward per metre of goal distance closed during the step (from the
    mover's position at the step's start to its goal then, against its distance to that goal at the step's end),
    added to ``reward_per_step`` for an active mover that neither collided nor reached its goal; 0 (default): off,
    the sparse reward bit for bit. ``reward_team`` (in [0, 1]): the share of each mover's reward replaced by the mean
    reward of its world's movers (``(1 - reward_team) * own + reward_team * mean``; the world's ``reward`` is the
    movers' own rewards summed, as without it), so that a correction that gains its mover a goal by costing its
    neighbours more is not learned as a gain (parameter-shared PPO on individual rewards is selfish); 0 (default):
    each mover its own reward, bit for bit."""

    num_movers: int = 64
    layout: Any = None
    occupancy: float = 0.25
    collision_shape: str = "circle"
    collision_size: float | tuple[float, float] | None = None
    collision_offset: float = 0.0
    collision_offset_wall: float = 0.0
    safety_margin: float = 0.0
    mover_params: dict | None = None
    learn_jerk: bool = False
    v_max: float = 2.0
    a_max: float = 10.0
    j_max: float = 100.0
    num_cycles: int = 40
    threshold_pos: float = 0.1
    reward_goal: float = 20.0
    reward_collision: float = -20.0
    reward_per_step: float = -1.0
    reward_progress: float = 0.0
    reward_team: float = 0.0
    on_collision: str = "respawn"
    max_episode_steps: int | None = None
    k: int = 8
    obs_radius: float = 1.0
    num_rays: int = 8
    ray_range: float = 1.0
    respawn_rounds: int = 2
    respawn_clearance: float = 0.1
    goal_rounds: int = 2
    reset_rounds: int = 32
    stations: Any = None
    num_stations: int = 4
    fused: bool | None = None
    graph: bool = True
    shield: bool = False
    shield_speed: float = SAFE_SPEED

    def __post_init__(self):
        if self.layout is not None and not isinstance(self.layout, (str, Layout)):  # a 0/1 array: kept as a Layout
            object.__setattr__(self, "layout", Layout(np.asarray(self.layout)))  # (compared by value)
        m = self.num_movers
        if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 1:
            raise ValueError(f"num_movers must be an integer >= 1, got {m!r}")
        if self.collision_shape not in ("circle", "box"):
            raise ValueError(f"collision_shape must be 'circle' or 'box', got {self.collision_shape!r}")
        if self.on_collision not in COLLISION_MODES:
            raise ValueError(f"on_collision must be one of {COLLISION_MODES}, got {self.on_collision!r}")
        if not (np.isfinite(self.respawn_clearance) and self.respawn_clearance >= 0):
            raise ValueError(f"respawn_clearance must be a number >= 0 (m), got {self.respawn_clearance!r}")
        if not (np.isfinite(self.occupancy) and self.occupancy > 0):
            raise ValueError(f"occupancy must be a positive number (movers per tile), got {self.occupancy!r}")
        if not (np.isfinite(self.threshold_pos) and self.threshold_pos > 0):
            raise ValueError(f"threshold_pos must be positive, got {self.threshold_pos!r}")
        if self.stations is not None and self.stations != "auto" and not (
                isinstance(self.stations, dict) and set(self.stations) == {"pickup", "dropoff"}):
            raise ValueError(f"stations must be None, 'auto' or a dict with 'pickup' and 'dropoff' positions, got "
                             f"{self.stations!r}")
        for name in ("num_cycles", "respawn_rounds", "goal_rounds", "reset_rounds", "num_stations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        for name in ("respawn_rounds", "goal_rounds", "reset_rounds"):  # each round is a launch of every step
            if getattr(self, name) > MAX_ROUNDS:
                raise ValueError(f"{name} must be at most {MAX_ROUNDS} (placement rounds run inside each step), got "
                                 f"{getattr(self, name)!r}")
        check_view_sizes(self.k, self.num_rays)
        if not isinstance(self.graph, (bool, np.bool_)):
            raise ValueError(f"graph must be True or False, got {self.graph!r}")
        if not isinstance(self.shield, (bool, np.bool_)):
            raise ValueError(f"shield must be True or False, got {self.shield!r}")
        if self.shield:
            if self.learn_jerk:
                raise ValueError("shield=True needs acceleration control (the safety filter commands accelerations): "
                                 "learn_jerk must be False, got learn_jerk=True")
            sp = self.shield_speed
            if isinstance(sp, bool) or not isinstance(sp, (int, float, np.integer, np.floating)) or not (
                    np.isfinite(sp) and 0 < sp <= self.v_max):
                raise ValueError(f"shield_speed must be a positive speed (m/s) at most v_max ({self.v_max!r}) with "
                                 f"shield=True, got shield_speed={sp!r}")
        if self.fused not in (None, True, False):
            raise ValueError(f"fused must be None, True or False, got {self.fused!r}")
        if self.fused:
            why = fused_applies(int(self.num_movers), self.on_collision)
            if why is not None:
                raise ValueError(f"fused=True does not apply: {why}")
        m = self.max_episode_steps
        if m is not None and (isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 1):
            raise ValueError(f"max_episode_steps must be None or an integer >= 1, got {m!r}")
        for name in ("reward_goal", "reward_collision", "reward_per_step", "reward_progress"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not (
                    np.isfinite(value)):
                raise ValueError(f"{name} must be finite (a number), got {value!r}")
        t = self.reward_team
        if isinstance(t, bool) or not isinstance(t, (int, float, np.integer, np.floating)) or not 0.0 <= t <= 1.0:
            raise ValueError(f"reward_team must be a number in [0, 1], got {t!r}")

    def make_layout(self) -> Layout:
        if self.layout is None:
            side = int(np.ceil(np.sqrt(self.num_movers / self.occupancy)))
            return Layout.grid(side, side)
        if isinstance(self.layout, str):  # a benchmark layout by name ("B0".."B9"); its mover count is not used
            return benchmark_layout(self.layout)[0]
        return self.layout  # (an array was made a Layout in __post_init__)

    def make_mover(self) -> MoverSpec:
        return make_mover_spec(self.collision_shape, self.collision_size, wall_margin=self.collision_offset_wall,
                               mover_params=self.mover_params, margin=self.safety_margin)


class SwarmEnv(MagwarpVecEnv):
    """Batched swarm env (see the module docstring). ``SwarmEnv(num_envs, config=None, **options)``."""

    benchmark_metrics = None  # a magwarp.metrics tracker, fed once per step (magwarp eval)
    #: the options' dataclass (a subclass env with more options has its own subclass of :class:`SwarmConfig`)
    config_type = SwarmConfig

    def __init__(self, num_envs: int = 1, config: SwarmConfig | None = None, *, device: str | None = None,
                 seed: int | None = None, render_mode: str | None = None, autoreset: bool = True,
                 check_inputs: bool = True, **options):
        cfg = resolve_config(type(self), config, options)
        self.config = cfg
        num_envs = as_count(num_envs, "num_envs")
        self.layout = cfg.make_layout()
        mover = cfg.make_mover()
        n, m = int(num_envs), int(cfg.num_movers)
        device = warp_device(device).alias
        respawn = cfg.on_collision == "respawn"
        # placeholder starts, replaced by the first reset below (never simulated nor validated)
        self.sim = Simulator(
            self.layout, m, n, mover=mover, start_xy=np.zeros((m, 2)), validate_starts=False,
            control="jerk" if cfg.learn_jerk else "acceleration", v_max=cfg.v_max, a_max=cfg.a_max,
            j_max=cfg.j_max, stop_on_collision=not respawn, device=device, check_inputs=False,
        )
        super().__init__(n, self.sim.torch_device, seed=seed, render_mode=render_mode, autoreset=autoreset,
                         check_inputs=check_inputs)
        self.num_movers = m
        self.learn_jerk = as_flag(cfg.learn_jerk, "learn_jerk")
        self.num_cycles = int(cfg.num_cycles)
        self.max_episode_steps = cfg.max_episode_steps
        self._build_placement(mover, seed, respawn)
        self._build_stops(respawn)
        self._alloc_task_state()
        self.stations = self._build_stations(mover, seed)
        self._alloc_step_state()
        # own state: velocity, goal relative to the mover, (acceleration), (carrying a job)
        self.own_dim = (6 if self.learn_jerk else 4) + (1 if self.stations is not None else 0)
        limit = cfg.j_max if cfg.learn_jerk else cfg.a_max
        self._set_spaces(gym.spaces.Box(-np.inf, np.inf, (m, self.own_dim + self.local.dim), np.float32),
                         gym.spaces.Box(-limit, limit, (m, 2), np.float32))
        # worlds end only by a collision in "end" mode or by the step limit: otherwise no reset work per step
        self._can_end = not respawn or self.max_episode_steps is not None
        self.reset(seed=seed)

    # ------------------------------------------------------------------ construction, by part
    def _build_placement(self, mover: MoverSpec, seed: int | None, respawn: bool) -> None:
        """The start and goal placer, the respawn placer (respawn rule), the local observations and the shield."""
        cfg, n, m, wdev = self.config, self.num_envs, self.num_movers, self.sim.device
        # the largest per-mover size: placement keeps every pair apart by the largest shape
        self.placer = Placer(self.layout, m, n, mover=mover, offset=cfg.collision_offset,
                             radius=float(self.sim._radii_np.max()), half_size=self.sim._half_np.max(axis=0),
                             device=wdev, seed=0 if seed is None else int(seed))
        self.respawn_placer = Placer(self.layout, m, n, mover=mover,
                                     offset=cfg.collision_offset + 0.5 * cfg.respawn_clearance,
                                     radius=float(self.sim._radii_np.max()), half_size=self.sim._half_np.max(axis=0),
                                     device=wdev, seed=1 if seed is None else int(seed) + 1) if respawn else None
        self.local = LocalObservations(self.layout, n, m, k=cfg.k, radius=cfg.obs_radius, num_rays=cfg.num_rays,
                                       max_range=cfg.ray_range, device=wdev)
        #: the shield's safety filter and its neighbour view (``shield=True``), else None
        self.shield_filter = self.shield_near = None
        if cfg.shield:
            self.shield_filter, self.shield_near = build_safety(
                self, v_cap=float(cfg.shield_speed), what=("shield_speed", "commit_brake", "safe_margin", "safe_k"))
        self._shield_info: dict[str, torch.Tensor] = {}

    def _build_stops(self, respawn: bool) -> None:
        """The per-mover stop marks, and under the respawn rule the stop hook and the fused step."""
        cfg, n, m = self.config, self.num_envs, self.num_movers
        self._stopped = wp.zeros((n, m), dtype=wp.int32, device=self.sim.device)
        self.stopped = wp.to_torch(self._stopped)
        self.fused_step = None
        if respawn:
            self.sim.add_cycle_hook(self._stop_hook)
            if cfg.fused is not False and fused_applies(m, cfg.on_collision) is None:
                # one launch per step; steps aside for the per-cycle path (this hook) while other hooks are attached
                self.fused_step = FusedSwarmStep(self.sim, self._stopped, self._stop_hook)
                self.sim.set_motion(self.fused_step)

    def _alloc_task_state(self) -> None:
        """Goals, counters, pending respawns and goals, the reward rule and the goal distances."""
        cfg, n, m, dev = self.config, self.num_envs, self.num_movers, self.device
        self.goals = torch.zeros(n, m, 2, device=dev)
        self.num_steps = torch.zeros(n, dtype=torch.int64, device=dev)
        self.collected_goals = torch.zeros(n, m, dtype=torch.int64, device=dev)
        self.respawn_pending = torch.zeros(n, m, dtype=torch.bool, device=dev)
        self.goal_pending = torch.zeros(n, m, dtype=torch.bool, device=dev)
        self._xy = torch.zeros(n, m, 2, device=dev)  # contiguous scratch positions for the placer
        self._xy_wp = wp.from_torch(self._xy, dtype=wp.vec2)
        self._goals_wp = wp.from_torch(self.goals, dtype=wp.vec2)
        self._no_flags = torch.zeros(0, 0, dtype=torch.bool, device=dev)  # job_done without stations
        rule = SwarmRewards()
        rule.threshold, rule.reward_goal = float(cfg.threshold_pos), float(cfg.reward_goal)
        rule.reward_collision, rule.reward_per_step = float(cfg.reward_collision), float(cfg.reward_per_step)
        rule.reward_progress = float(cfg.reward_progress)
        self._rule = rule
        # the progress reward's d_before: each mover's goal distance at the step's start (refreshed only when on)
        self.goal_dist = torch.zeros(n, m, device=dev)
        self._goal_dist_wp = wp.from_torch(self.goal_dist)

    def _build_stations(self, mover: MoverSpec, seed: int | None):
        """The material-flow stations (``stations`` option), or None."""
        cfg, wdev = self.config, self.sim.device
        if cfg.stations is None:
            return None
        from magwarp.swarm.stations import Stations

        if cfg.stations == "auto":
            return Stations.auto(self.layout, mover, cfg.num_stations, offset=cfg.collision_offset, device=wdev,
                                 seed=0 if seed is None else int(seed))
        return Stations(cfg.stations["pickup"], cfg.stations["dropoff"], self.layout, mover,
                        offset=cfg.collision_offset, device=wdev)

    def _alloc_step_state(self) -> None:
        """Jobs, the step kernel's marks and Warp views, the step's fixed input, device counters and graph slots."""
        cfg, n, m = self.config, self.num_envs, self.num_movers
        dev, wdev = self.device, self.sim.device
        self.carrying = torch.zeros(n, m, dtype=torch.bool, device=dev)
        self.jobs = torch.zeros(n, m, dtype=torch.int64, device=dev)
        # what the step kernel marks for _end_step (a new goal, a respawn), and Warp views of the state it updates
        self._want_goal = torch.zeros(n, m, dtype=torch.bool, device=dev)
        self._want_respawn = torch.zeros(n, m, dtype=torch.bool, device=dev)
        self._task_wp = [wp.from_torch(t) for t in (self.respawn_pending, self.goal_pending, self.carrying,
                                                     self._want_goal, self._want_respawn, self.collected_goals,
                                                     self.jobs)]
        # the step's fixed input and device counters (a recorded step graph reads and advances them in place)
        self._action = torch.zeros(n, m, 2, device=dev)
        self._action_wp = wp.from_torch(self._action, dtype=wp.vec2)
        self._env_steps = torch.zeros(1, dtype=torch.int64, device=dev)  # env steps since construction, on the device
        self._env_steps_wp = wp.from_torch(self._env_steps)
        self._num_steps_wp = wp.from_torch(self.num_steps)
        self._none_vec2 = wp.empty((0, 0), dtype=wp.vec2, device=wdev)
        self.graph = bool(cfg.graph)  # settable: False runs the same launches eagerly
        self._graphs: list[_StepGraph | None] = [None, None]
        self._graph_key_value = None
        self._slot = 0
        self._in_capture = False

    # ------------------------------------------------------------------ hooks of the simulator
    def _stop_hook(self, sim: Simulator) -> None:
        s = sim.state
        wp.launch(stop_collided, dim=(self.num_envs, self.num_movers), device=sim.device,
                  inputs=[s.flags], outputs=[self._stopped, s.vel, s.acc, s.cmd])

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            self.placer.reseed(int(seed))
            if self.respawn_placer is not None:
                self.respawn_placer.reseed(int(seed) + 1)
        self._checked_reset = True  # reset(): placement is checked on the host (errors with densities)
        try:
            return super().reset(seed=seed, options=options)
        finally:
            self._checked_reset = False

    def step(self, action):
        """Simulate, reward, then stream goals and respawn collided movers; the observation shows the result.

        On CUDA with ``graph`` (:attr:`step_path` ``"graph"``) the step after the input check and the action's copy is
        one CUDA graph replay, and the returned tensors are that graph's outputs: valid through the next step,
        overwritten by the one after it (two graphs alternate). Elsewhere the same launches run eagerly and return
        fresh tensors."""
        action = self._check_action(action)
        with torch.inference_mode(False):  # the env's buffers are updated in place in and outside inference mode
            self._action.copy_(action)
            out = self._graph_step() if self._graph_blocker() is None else self._launch_step()
        self._step_count += 1
        return out

    @property
    def step_path(self) -> str:
        """Which step :meth:`step` runs now: ``"graph"`` (CUDA: one graph replay) or ``"eager (REASON)"`` (the same
        launches one by one: ``graph=False``, the CPU, benchmark metrics, a step hook replaced on the instance or a
        capture that failed)."""
        why = self._graph_blocker()
        return "graph" if why is None else f"eager ({why})"

    def _graph_blocker(self) -> str | None:
        if not self.graph:
            return "graph=False"
        if not self.sim.device.is_cuda:
            return "the CPU"
        if self.benchmark_metrics is not None:
            return "benchmark metrics"
        replaced = next((h for h in STEP_HOOKS if h in vars(self)), None)
        if replaced is not None:
            return f"{replaced} replaced on the instance"
        return None

    def _launch_step(self):
        """Every launch of one env step (the action already in ``_action``), on the current streams, no host sync:
        run eagerly, or recorded once as the step's CUDA graph (:meth:`_graph_step`)."""
        self._apply_action(self._action)
        reward, terminated, truncated, info = self._evaluate(None)
        if self.shield_filter is not None:
            info.update(self._shield_info)
        self._end_step(None, info)
        obs = self._get_obs()
        # the world's reward and flags, and the NaN guard: a non-finite world is flagged (info["nonfinite"]), rewarded
        # 0 and terminated (with respawns and no time limit, worlds never end: it stays flagged)
        done = self._finish(obs, reward, terminated, truncated, info)
        if self.benchmark_metrics is not None:
            info["metrics"] = self.benchmark_metrics.on_step(obs, info, terminated, truncated)
        if self.autoreset and self._can_end:
            info["final_obs"] = obs
            info["_final_obs"] = done
            self._reset_envs(done)
            obs = torch.where(done[:, None, None], self._get_obs(), obs)
        return obs, reward, terminated, truncated, info

    def _graph_key(self) -> tuple:
        """What the recorded launches depend on beyond the arrays they update in place: a change (new kernels,
        replaced arrays, another search or launch shape) records the graphs anew."""
        sim, fs, rp, local = self.sim, self.fused_step, self.respawn_placer, self.local
        m = sim.model
        return (id(sim.state), sim._motion, tuple(sim._hooks), tuple(sim._pre_hooks), id(sim._actuator),
                id(sim._delay), id(sim._prev_cmd), sim._latency_bound, sim.nan_guard, sim._fused,
                id(sim._fused_kernel), id(sim._advance_kernel), id(m.body), id(m.radius), id(m.half_size),
                id(m.margins),
                None if fs is None else (fs.tiled, exchange(), launch_block(self.num_movers), guard_in_step()),
                self.placer.shape,
                None if rp is None else rp.shape, self._search_key(local), self.autoreset, self._can_end,
                id(self._generator), self.num_cycles,
                None if self.shield_near is None else self._search_key(self.shield_near))

    @staticmethod
    def _search_key(local: LocalObservations) -> tuple:
        return (local.search, local.staged, local.tiled, local.unrolled, local.merge, local.rect, local.sift)

    def _graph_step(self):
        """One step by graph replay (slot 0 and 1 alternate); a slot's first step runs eagerly, then is recorded."""
        key = self._graph_key()
        if key != self._graph_key_value:
            self._graphs = [None, None]
            self._graph_key_value = key
        slot = self._slot
        rec = self._graphs[slot]
        if rec is None:
            out = self._launch_step()  # a real step, eagerly: loads every kernel before the capture
            local = self.local
            views = (local.rel_pos, local.rel_vel, local.walls)
            try:
                self._graphs[slot] = self._capture()
                self._slot = slot ^ 1
            except Exception as e:  # noqa: BLE001 - any capture failure: report it and run eagerly
                import warnings

                warnings.warn(f"SwarmEnv: the step could not be captured as a CUDA graph ({type(e).__name__}: {e}); "
                              "it runs the same launches eagerly (graph=False)", RuntimeWarning, stacklevel=3)
                self.graph = False
                self._graphs = [None, None]
                self._replace_generator()
            finally:
                local.rel_pos, local.rel_vel, local.walls = views  # the capture pointed them at its own tensor
            return out
        for callback in self.sim._step_callbacks:  # as sim.step runs them (host work before the step)
            callback()
        rec.recorded.graph.replay()
        self.local.rel_pos, self.local.rel_vel, self.local.walls = rec.views
        self._slot = slot ^ 1
        obs, reward, terminated, truncated, info = rec.recorded.outputs
        return obs, reward, terminated, truncated, dict(info)

    def _capture(self) -> _StepGraph:
        """Record :meth:`_launch_step` as one CUDA graph (nothing runs); the env's generator (the stations' draws) is
        registered with it, so each replay draws fresh numbers."""
        gens = (self._generator,) if self.stations is not None else ()
        self._in_capture = True
        try:
            recorded = record_cuda_graph(self._launch_step, self.device, generators=gens)
        finally:
            self._in_capture = False
        local = self.local
        return _StepGraph(recorded, (local.rel_pos, local.rel_vel, local.walls))

    def _replace_generator(self) -> None:
        """A new env generator that continues from the old one (:func:`~magwarp.envs.step_graph.continued_generator`:
        a failed capture may leave the old one registered with a dead graph)."""
        self._generator = continued_generator(self._generator)

    # ------------------------------------------------------------------ task hooks
    def _place(self, xy: torch.Tensor, mask: torch.Tensor, rounds: int, hold: bool = False,
               placer: Placer | None = None) -> torch.Tensor:
        """Place the masked rows of ``xy`` (contiguous ``[N, M, 2]``); returns the movers left unplaced. ``hold``:
        the masked rows are real spots until they move (respawns, goal streams)."""
        placer = placer or self.placer
        if getattr(self, "_checked_reset", False):
            placer.place(xy, mask)
            return torch.zeros_like(mask)
        return placer.place_async(xy, mask, rounds=rounds, hold=hold)

    def _reset_envs(self, mask: torch.Tensor) -> None:
        n, m = self.num_envs, self.num_movers
        movers = mask[:, None].expand(n, m)
        start = self.sim.start_pos
        self._xy.copy_(start[..., :2])
        left = self._place(self._xy, movers, self.config.reset_rounds)
        start[..., :2] = self._xy
        self._reset_sim(mask)
        if self.stations is not None:
            self.carrying.masked_fill_(movers, False)
            self.jobs.masked_fill_(movers, 0)
            self.goals.copy_(torch.where(movers[..., None], self.stations.sample(self.carrying, self._generator),
                                         self.goals))
            goal_left = torch.zeros_like(movers)
        else:
            goal_left = self._place(self.goals, movers, self.config.reset_rounds)
        self.stopped.copy_(torch.where(movers, left.to(torch.int32), self.stopped))
        self.respawn_pending.copy_(torch.where(movers, left, self.respawn_pending))
        self.goal_pending.copy_(torch.where(movers, goal_left, self.goal_pending))
        self.num_steps.masked_fill_(mask, 0)
        self.collected_goals.masked_fill_(mask[:, None], 0)
        self._refresh_goal_dist()
        if self.benchmark_metrics is not None:
            self.benchmark_metrics.episode_reset(mask)

    def _reset_sim(self, mask: torch.Tensor) -> None:
        """The simulator's reset of the worlds in ``mask`` (``[W]`` bool) on the current streams (``sim.reset``
        launches on the simulator's own stream, which a capture cannot follow): the same kernels."""
        sim = self.sim
        sim._t(sim._reset_mask).copy_(mask)
        with on_torch_stream(sim.device):
            sim._launch_reset()

    def _shield(self, action: torch.Tensor) -> torch.Tensor:
        """The shield (``shield=True``, the module docstring): ``action`` through the safety filter, as
        :class:`~magwarp.swarm.SwarmPlanner`'s last steps; sets ``_shield_info`` (what the step's info gets). Torch
        operations and Warp launches on the current stream, no host sync (it runs inside the step's graph)."""
        sim, safety, near = self.sim, self.shield_filter, self.shield_near
        pos, vel = sim.pos[..., :2], sim.vel[..., :2]
        a_max, step = safety.a_max, safety.step
        # the velocity after one step of the action as the simulator applies it (norm-clipped at a_max)
        acc = clip_norm(action, a_max)
        wanted = vel + step * acc
        near.compute(sim.state.pos, sim.state.vel)
        safe, passes = safety.choose(vel, wanted, near.rel_pos, near.rel_vel, near.mask, pos)
        # the acceleration that reaches the safe velocity within the step, within the limit (the planner's step 4)
        cmd = clip_norm((safe - vel) / step, a_max)
        active = ~passes & (self.stopped == 0)
        delta = torch.where(active, (cmd - acc).norm(dim=-1), 0.0)
        self._shield_info = {"shield_active": active, "shield_delta": delta}
        return torch.where(active[..., None], cmd, action).contiguous()

    def _apply_action(self, action: torch.Tensor) -> None:
        # stopped movers (pending respawns) ignore their command; the stop hook keeps them still
        sim = self.sim
        if self.shield_filter is not None:
            action = self._shield(action)
        act = self._action_wp if action is self._action else wp.from_torch(action.contiguous(), dtype=wp.vec2)
        with on_torch_stream(sim.device):
            wp.launch(command_unless_stopped, dim=(self.num_envs, self.num_movers), device=sim.device,
                      inputs=[self._stopped, act], outputs=[sim.state.cmd, self._env_steps_wp])
            if self._in_capture:  # the simulator's launches into the env's graph (sim.step replays its own graph)
                sim._launch_step(self.num_cycles)
        if not self._in_capture:
            sim.step(self.num_cycles)

    def _get_obs(self) -> torch.Tensor:
        sim = self.sim
        obs = torch.empty(self.num_envs, self.num_movers, self.own_dim + self.local.dim, device=self.device)
        return self.local.observe(sim.state.pos, sim.state.vel, obs, goals=self.goals,
                                  acc=sim.acc if self.learn_jerk else None,
                                  carrying=self.carrying if self.stations is not None else None)

    def _evaluate(self, obs) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        """The step's outcome per mover in one kernel (:func:`~magwarp.kernels.swarm.evaluate_movers`), which also
        counts the goals (and jobs), marks the movers that want a new goal or a respawn, for :meth:`_end_step`, and
        copies the positions the respawn placer starts from. The world's ``reward``, ``terminated`` and ``truncated``
        are returned unfilled: :meth:`_finish` writes them after the observation (with the NaN guard)."""
        cfg = self.config
        n, m, dev = self.num_envs, self.num_movers, self.device

        def flags(*shape):
            return torch.empty(*shape, dtype=torch.bool, device=dev)

        agent_reward = torch.empty(n, m, device=dev)
        mover_col, wall_col, collided, reached = flags(n, m), flags(n, m), flags(n, m), flags(n, m)
        job_done = flags(n, m) if self.stations is not None else self._no_flags
        collected = torch.empty(n, m, dtype=torch.int64, device=dev)
        xy = self._xy_wp if cfg.on_collision == "respawn" else self._none_vec2
        w = wp.from_torch
        with on_torch_stream(self.sim.device):
            wp.launch(evaluate_movers, dim=(n, m), device=self.sim.device,
                      inputs=[self._rule, self.sim.state.flags_any, self.sim.state.pos, self._goals_wp,
                              *self._task_wp[:3], self._goal_dist_wp],
                      outputs=[w(agent_reward), w(mover_col), w(wall_col), w(collided), w(reached), w(job_done),
                               *self._task_wp[3:], w(collected), xy])
        reward, terminated, truncated = torch.empty(n, device=dev), flags(n), flags(n)
        agent_terminated = collided | collided.any(dim=1, keepdim=True) if cfg.on_collision == "end" else collided
        info = {"agent_reward": agent_reward, "mover_collision": mover_col, "wall_collision": wall_col,
                "agent_terminated": agent_terminated, "goal_reached": reached, "collided": collided,
                "collected_goals": collected}
        if self.stations is not None:
            info["job_done"] = job_done
        return reward, terminated, truncated, info

    def _end_step(self, obs, info) -> None:
        """Goal streams (or stations) and respawns for the movers :meth:`_evaluate` marked (its kernel already
        counted the goals and jobs)."""
        cfg = self.config
        reached = info["goal_reached"]
        if self.stations is not None:
            # material flow: a pick-up loads a job (next: a drop-off), a drop-off delivers it (next: a pick-up)
            self.carrying.copy_(self.carrying ^ reached)
            self.goals.copy_(torch.where(reached[..., None], self.stations.sample(self.carrying, self._generator),
                                         self.goals))
            info["jobs"] = self.jobs.clone()
        else:
            # goal streams: new goals clear of the other goals
            self.placer.place_async(self.goals, self._want_goal, rounds=cfg.goal_rounds, hold=True,
                                    out=self.goal_pending)
        if cfg.on_collision == "respawn":
            info["respawn_pending"] = self._respawn(self._want_respawn)
        else:
            info["respawn_pending"] = self.respawn_pending.clone()
        self._refresh_goal_dist()

    def _refresh_goal_dist(self) -> None:
        """The progress reward's ``d_before`` (``goal_dist``): every mover's distance to its goal now, after the
        step's new goals and respawns or a reset (one launch on the current stream; none with ``reward_progress``
        0)."""
        if self._rule.reward_progress == 0.0:
            return
        sim = self.sim
        with on_torch_stream(sim.device):
            wp.launch(goal_distances, dim=(self.num_envs, self.num_movers), device=sim.device,
                      inputs=[sim.state.pos, self._goals_wp], outputs=[self._goal_dist_wp])

    def _respawn(self, want: torch.Tensor) -> torch.Tensor:
        """Re-place the movers in ``want`` at free spots (clear of every other mover) and restart them at rest, from
        the positions :meth:`_evaluate`'s kernel copied into ``_xy``; returns a copy of the new pending respawns
        (``info["respawn_pending"]``, written by the same kernel)."""
        sim = self.sim
        left = self.respawn_placer.place_device(self._xy, want, rounds=self.config.respawn_rounds, hold=True)
        pending = torch.empty(self.num_envs, self.num_movers, dtype=torch.bool, device=self.device)
        s, w = sim.state, wp.from_torch
        with on_torch_stream(sim.device):
            wp.launch(apply_respawns, dim=(self.num_envs, self.num_movers), device=sim.device,
                      inputs=[w(want), left, self._xy_wp],
                      outputs=[s.pos, s.vel, s.acc, s.cmd, self._stopped, self._task_wp[0], w(pending)])
        return pending

    def _finish(self, obs, reward, terminated, truncated, info) -> torch.Tensor:
        """The world's ``reward``, ``terminated`` and ``truncated`` (filled in place), its episode's step count and
        the NaN guard (``info["nonfinite"]``, ``info["nonfinite_step"]``) in one kernel over the worlds
        (:func:`~magwarp.kernels.swarm.finish_worlds`; it reads the observation kernel's non-finite flags, so it runs
        after :meth:`_get_obs`). Returns ``done`` (terminated or truncated), the autoreset's mask."""
        n, dev, sim = self.num_envs, self.device, self.sim
        nonfinite = torch.empty(n, dtype=torch.bool, device=dev)
        nonfinite_step = torch.empty(n, dtype=torch.int64, device=dev)
        done = torch.empty(n, dtype=torch.bool, device=dev)
        w = wp.from_torch
        limit = 0 if self.max_episode_steps is None else int(self.max_episode_steps)
        with on_torch_stream(sim.device):
            wp.launch(finish_worlds, dim=n, device=sim.device,
                      inputs=[int(self.config.on_collision == "end"), limit, w(info["agent_reward"]),
                              w(info["collided"]), sim._nonfinite, self.local._nonfinite, self._env_steps_wp],
                      outputs=[self._num_steps_wp, w(reward), w(terminated), w(truncated), w(nonfinite),
                               w(nonfinite_step), w(done)])
        info["nonfinite"] = nonfinite
        info["nonfinite_step"] = nonfinite_step
        team = float(self.config.reward_team)
        if team > 0.0:  # after the world's reward (the own rewards' sum): each mover's share of the world's mean
            agent_reward = info["agent_reward"]
            agent_reward.lerp_(agent_reward.mean(dim=1, keepdim=True), team)
        return done

    def agent_view(self):
        """The flat parameter-shared view of this env (:class:`~magwarp.swarm.FlatSwarmEnv`): every mover of every
        world is one sub-env; what ``magwarp train`` trains on (IPPO: one network, local observations)."""
        from magwarp.swarm.views import FlatSwarmEnv

        return FlatSwarmEnv(self)

    def scripted_policy(self):
        """The scripted ORCA planner (:class:`~magwarp.swarm.SwarmPlanner`) as a policy: ``action = policy(obs)``."""
        from magwarp.swarm.planner import SwarmPlanner

        return SwarmPlanner(self)

    # ------------------------------------------------------------------ rendering
    def set_render_view(self, *, window=None, px_per_tile: int | None = None, max_image_px: int = 1024) -> None:
        """How ``render()`` draws (:mod:`magwarp.render.swarm`): the whole world (default) or ``window``
        ``(cx, cy, width, height)`` m of it, at ``px_per_tile`` (default: the most that keeps the image within
        ``max_image_px``, up to 48). Movers are coloured by state (moving, idle, collided, carrying, waiting);
        below 12 pixels per tile they are dots of at least 2 x 2 pixels; goals are drawn from 24 pixels per tile on.
        Checked here (a bad window raises)."""
        self._render_view = {"window": window, "px_per_tile": px_per_tile, "max_image_px": max_image_px}
        self._renderer = self._make_renderer()

    @property
    def render_states(self) -> tuple[str, ...]:
        """The mover states ``render()`` colours (names of :data:`magwarp.render.colors.STATE_NAMES`)."""
        from magwarp.render.colors import STATE_NAMES

        return tuple(n for n in STATE_NAMES if n != "carrying" or self.stations is not None)

    def _make_renderer(self):
        from magwarp.render.swarm import swarm_renderer

        view = getattr(self, "_render_view", None) or {}
        worlds = getattr(self, "_render_worlds", None) or 1
        renderer, self._render_goals = swarm_renderer(self.layout, self.sim.mover, worlds=worlds,
                                                       device=self.sim.device, **view)
        return renderer

    def _render_frame(self) -> torch.Tensor:
        from magwarp.render.swarm import mover_states

        if getattr(self, "_renderer", None) is None:
            self._renderer = self._make_renderer()
        sim = self.sim
        collided = sim.flags_any != 0
        state = mover_states(sim.vel, sim.pos, self.goals, collided, self.carrying if self.stations is not None
                             else None, self.respawn_pending, self.config.threshold_pos)
        return self._renderer.draw(sim.pos, sim.quat, flags=sim.flags_any, radii=sim.radii, half_sizes=sim.half_sizes,
                                   goals=self.goals if self._render_goals else None, state=state)
