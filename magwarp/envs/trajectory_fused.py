"""The trajectory-planning env's fused step: physics, observations, rewards, terminations, goal resampling, NaN guard
and autoreset in a handful of launches, captured as one CUDA graph on a GPU.

One step (after the host-side input check and the copy of the action into the simulator's command buffer) is:

1. the simulator's step kernels (``num_cycles`` cycles, NaN guard);
2. the random numbers of the goals and starts, drawn with the env's torch generator in the same calls, shapes and
   order as the eager step draws them (goals for reached goals; a start configuration and goals for every world), so
   that both paths give the same episodes for the same seed. The sensor and latency models draw nothing here: their
   draws are counter-based (:mod:`magwarp.kernels.sensor_draws`), computed in the kernels of steps 3 and 5 from the
   env's draw key and the device clock (as the torch step's fill kernels compute them);
3. :func:`magwarp.kernels.task.trajectory_step` (one thread per world): the final (sensed) observation, reward,
   flags, info, goal counters, resampled goals, and the next episode's starts, goals and (with a latency range)
   delays for the worlds that finished;
4. for those worlds (the kernel's ``done`` flags as the mask, on the device): the sensor model's new biases (in
   step 3's kernel) and the reset-mode randomisation terms
   (:meth:`~magwarp.envs.planar_randomization.PlanarRandomizer.reset_in_step`: two kernels, the torch step's too);
   the simulator's reset kernels;
5. :func:`magwarp.kernels.task.trajectory_obs`: the returned observation; the sensor model keeps it (what a dropped
   reading repeats); the next step's clock (env steps and draw clock: two device rows that the two alternating step
   graphs read and write crosswise, since a kernel cannot advance a counter all its threads read).

Interval-mode randomisation terms fire before the step (the simulator's step callbacks, as in the torch step: one
launch of the randomiser's kernel when a term is due), then the graph is replayed.

On CUDA, step 2's draws run on a second stream beside step 1 and step 4's firing beside the rest of steps 4 and 5
(neither is read by what runs beside it; both are joined before the step ends), so the step's graph has two parallel
branches (:class:`magwarp._streams.SideBranch`; ``MAGWARP_STEP_BRANCHES=off`` runs everything in order, same results).

On CUDA (``graph=True``) steps 1-5 are one CUDA graph recorded with ``torch.cuda.graph`` (the env's generator is
registered with it, so every replay draws new numbers), replayed with no host sync and no Python beyond the replay.
The first step runs eagerly (it loads the kernels) and the graph is recorded after it. On the CPU the same kernels
run eagerly (the simulator's own step is a Warp CPU graph).

The returned tensors are the env's buffers, not copies: two sets alternate, so a step's tensors stay valid through
the next step (``obs = next_obs`` loops, replay buffers that copy) and are overwritten by the step after it. Clone
what you keep longer.
"""

from __future__ import annotations

import functools

import torch
import warp as wp

from magwarp._streams import SideBranch
from magwarp.envs.step_graph import RecordedGraph, record_cuda_graph
from magwarp.kernels import task as ktask
from magwarp.kernels.options import STEP_BRANCHES

__all__ = ["FusedTrajectoryStep", "fused_step_blocker"]


#: the task hooks the fused step replaces: a subclass that overrides one keeps the torch step
REPLACED_HOOKS = ("_reset_envs", "_apply_action", "_get_obs", "_evaluate", "_end_step", "_nonfinite_worlds",
                  "_guard_nonfinite", "compute_reward", "goal_distance")


@functools.cache
def _overridden_hook(cls) -> str | None:
    from magwarp.envs.trajectory import TrajectoryPlanningEnv

    return next((h for h in REPLACED_HOOKS if getattr(cls, h) is not getattr(TrajectoryPlanningEnv, h)), None)


def fused_step_blocker(env) -> str | None:
    """Why ``env`` (a :class:`~magwarp.envs.trajectory.TrajectoryPlanningEnv`) must take the eager torch step now, or
    None when the fused step applies. The fused step covers the default configuration, action latency (fixed or
    drawn at resets), the sensor models (bias, white noise, dropped readings; ``std_noise``), domain randomisation
    terms of every mode (startup; reset: inside the step; interval: on the host before the step, as the simulator's
    step callbacks run), ``learn_jerk``, box or circle shapes, any layout, ``max_episode_steps`` and
    ``timeout_steps``; a pre-cycle hook marked ``fused_step_safe`` (device launches only, no host work: the magnetic
    drive's) runs inside the fused step (and its graph) as in the torch step. Benchmark metrics, ``nan_dump``,
    ``autoreset=False``, other simulator cycle hooks and subclasses that override a task hook
    (:data:`REPLACED_HOOKS`) keep the torch step."""
    if not env.fused:
        return "fused=False"
    if not env.autoreset:
        return "autoreset=False"
    if env.nan_dump is not None:
        return "nan_dump"
    if env.benchmark_metrics is not None:
        return "benchmark metrics"
    if env.sim._hooks or not all(getattr(h, "fused_step_safe", False) for h in env.sim._pre_hooks):
        return "simulator cycle hooks"
    hook = _overridden_hook(type(env))
    if hook is not None:
        return f"{type(env).__name__} overrides {hook}"
    return None


class _Outputs:
    """One set of the step's returned tensors (the env's buffers) and their Warp views."""

    def __init__(self, n: int, m: int, obs_dim: int, device: torch.device):
        def f32(*shape):
            return torch.zeros(shape, dtype=torch.float32, device=device)

        def flag(*shape):
            return torch.zeros(shape, dtype=torch.bool, device=device)

        def i64(*shape):
            return torch.zeros(shape, dtype=torch.int64, device=device)

        self.obs = {"observation": f32(n, obs_dim), "achieved_goal": f32(n, 2 * m), "desired_goal": f32(n, 2 * m)}
        self.final = {"observation": f32(n, obs_dim), "achieved_goal": f32(n, 2 * m), "desired_goal": f32(n, 2 * m)}
        self.reward, self.terminated, self.truncated = f32(n), flag(n), flag(n)
        self.mover_collision, self.wall_collision, self.time_limit = flag(n), flag(n), flag(n)
        self.steps_since_goal, self.collected, self.goals_reached = i64(n), i64(n, m), flag(n, m)
        self.nonfinite, self.nonfinite_step, self.done = flag(n), i64(n), flag(n)
        w = wp.from_torch
        self.step_outputs = [
            w(self.final["observation"]), w(self.final["achieved_goal"]), w(self.final["desired_goal"]),
            w(self.reward), w(self.terminated), w(self.truncated), w(self.mover_collision), w(self.wall_collision),
            w(self.steps_since_goal), w(self.collected), w(self.goals_reached), w(self.time_limit), w(self.nonfinite),
            w(self.nonfinite_step), w(self.done),
        ]
        self.obs_wp = [w(self.obs["observation"]), w(self.obs["achieved_goal"]), w(self.obs["desired_goal"])]

    def returns(self, time_limit: bool):
        """``obs, reward, terminated, truncated, info`` with the eager step's keys (fresh dicts, shared tensors)."""
        info = {"mover_collision": self.mover_collision, "wall_collision": self.wall_collision,
                "steps_since_goal": self.steps_since_goal, "collected_goals": self.collected}
        if time_limit:
            info["time_limit"] = self.time_limit
        info.update(goals_reached=self.goals_reached, nonfinite=self.nonfinite, nonfinite_step=self.nonfinite_step,
                    final_obs=dict(self.final), _final_obs=self.done)
        return dict(self.obs), self.reward, self.terminated, self.truncated, info


class FusedTrajectoryStep:
    """The fused step of one :class:`~magwarp.envs.trajectory.TrajectoryPlanningEnv` (see the module docstring)."""

    def __init__(self, env, graph: bool = True):
        self.env = env
        sim, sampler = env.sim, env.sampler
        n, m = env.num_envs, env.num_movers
        dev = env.device
        self.graph = bool(graph) and sim.device.is_cuda
        self._outputs = [_Outputs(n, m, env.single_observation_space["observation"].shape[0], dev) for _ in range(2)]
        self._slot = 0
        self._graphs: list = [None, None]
        self._graph_key = None
        # Random draws (filled by torch in the eager step's order; the kernels select among them).
        c = sampler.candidates
        self._step_u = torch.zeros(n, m, c, 2, device=dev)
        self._step_fallback = torch.zeros(n, m, dtype=torch.int64, device=dev)
        self._start_index = torch.zeros(n, dtype=torch.int64, device=dev)
        self._reset_u = torch.zeros(n, m, c, 2, device=dev)
        self._reset_fallback = torch.zeros(n, m, dtype=torch.int64, device=dev)
        self._delay_range = env.latency.draw_range
        self._no_delay = wp.zeros(n, dtype=wp.int32, device=sim.device)  # the kernel's delay output without a range
        # Stable copies of the sampler's pools (reset(seed=...) redraws them; they are copied in, same sizes).
        self._goal_pool = sampler.goal_pool.clone()
        self._start_pool = sampler.start_pool.clone()
        self._pool_sources = (sampler.goal_pool, sampler.start_pool)
        # The device clocks: row s is read by the steps of slot s, and written (the next step's) by the other slot's:
        # [env steps before the step (for info["nonfinite_step"]), the sim2real models' draw clock]; the host values
        # they were last set from.
        self._clock = torch.zeros(2, 2, dtype=torch.int64, device=dev)
        self._clock_host = None
        self._cmd = sim.cmd
        # Warp views of the env's and these buffers (all stable: converted once).
        w = wp.from_torch
        self._wp = {
            "goal_pool": w(self._goal_pool, dtype=wp.vec2), "start_pool": w(self._start_pool, dtype=wp.vec2),
            "clock": [w(self._clock[0]), w(self._clock[1])], "key": w(env.draw_clock.key),
            "step_u": w(self._step_u, dtype=wp.vec2),
            "step_fallback": w(self._step_fallback), "start_index": w(self._start_index),
            "reset_u": w(self._reset_u, dtype=wp.vec2), "reset_fallback": w(self._reset_fallback),
            "goals": w(env.goals, dtype=wp.vec2), "num_steps": w(env.num_steps),
            "last_goal_step": w(env.last_goal_step), "collected": w(env.collected_goals),
        }

        task = ktask.TrajectoryTask()
        task.learn_jerk = 1 if env.learn_jerk else 0
        task.threshold = env.threshold_pos
        task.reward_success = env.reward_success
        task.reward_collision = env.reward_collision
        task.reward_per_step = env.reward_per_step
        task.timeout_steps = -1 if env.timeout_steps is None else int(env.timeout_steps)
        task.max_episode_steps = -1 if env.max_episode_steps is None else int(env.max_episode_steps)
        task.draw_latency = 0 if self._delay_range is None else 1
        low, high = self._delay_range or (0, 0)
        task.delay_low, task.delay_span = low, high - low + 1
        self._task = task
        s = ktask.GoalSampler()
        lo, span = sampler.lo.cpu(), sampler.span.cpu()
        s.lo, s.span = wp.vec2(*lo.tolist()), wp.vec2(*span.tolist())
        s.hi = wp.vec2(*(sampler.lo + sampler.span).cpu().tolist())  # rounded as the sampler's test rounds it
        s.candidates = int(c)
        s.full_rect = 1 if sampler.full_rectangle else 0
        s.radius = sampler.radius
        s.half = wp.vec2(*sampler.half.tolist())
        s.offset = sampler.offset
        self._sampler = s
        self._init_sensors(n, m)
        # a second stream for the work the next launches do not read (kernels.options.STEP_BRANCHES)
        self._draws = SideBranch(dev, STEP_BRANCHES == "on")
        self._firing = SideBranch(dev, STEP_BRANCHES == "on")

    def _init_sensors(self, n: int, m: int) -> None:
        """The sensor model on the device (:class:`magwarp.kernels.task.SensorParams`: its biases, dropped-reading
        flags and held readings are the model's own tensors, updated in place; the kernels compute its draws)."""
        sensors, wdev = self.env.sensors, self.env.sim.device
        cfg = sensors.config
        w = wp.from_torch

        def vec2(t: torch.Tensor | None):
            return w(t.reshape(n, m, 2), dtype=wp.vec2) if t is not None else wp.empty((0, 0), dtype=wp.vec2,
                                                                                         device=wdev)

        def mean(name: str, bias: torch.Tensor | None) -> torch.Tensor | None:
            return None if bias is None else torch.broadcast_to(sensors._mean[name], bias.shape).contiguous()

        self._means = (mean("vel", sensors.vel_bias), mean("pos", sensors.pos_bias))
        p = ktask.SensorParams()
        p.pos_bias_on, p.vel_bias_on = int(sensors.pos_bias is not None), int(sensors.vel_bias is not None)
        p.pos_std, p.vel_std = float(cfg.pos_noise_std), float(cfg.vel_noise_std)
        p.pos_bias_std = float(cfg.pos_bias_std) if sensors.pos_bias is not None else 0.0
        p.vel_bias_std = float(cfg.vel_bias_std) if sensors.vel_bias is not None else 0.0
        p.dropout, p.drop_prob = int(cfg.dropout_prob > 0), float(cfg.dropout_prob)
        p.pos_bias, p.vel_bias = vec2(sensors.pos_bias), vec2(sensors.vel_bias)
        p.vel_mean, p.pos_mean = vec2(self._means[0]), vec2(self._means[1])
        p.drop = w(sensors._drop)
        held = sensors._held if p.dropout else None
        none2d = wp.empty((0, 0), dtype=float, device=wdev)
        p.held_obs = w(held["observation"]) if held is not None else none2d
        p.held_achieved = w(held["achieved_goal"]) if held is not None else none2d
        self._sensor = p

    # ------------------------------------------------------------------ launches
    def _sim_arrays(self):
        """The simulator arrays the kernels touch (looked up per launch/capture: set_latency replaces some)."""
        sim = self.env.sim
        st = sim.state
        delay = sim._delay if self._delay_range is not None else self._no_delay
        return st, delay

    def _draw(self) -> None:
        env, sampler = self.env, self.env.sampler
        g = sampler.generator
        n, m = env.num_envs, env.num_movers
        torch.rand(self._step_u.shape, generator=g, out=self._step_u)
        torch.randint(len(sampler.goal_pool), (n, m), generator=g, out=self._step_fallback)
        torch.randint(len(sampler.start_pool), (n,), generator=g, out=self._start_index)
        torch.rand(self._reset_u.shape, generator=g, out=self._reset_u)
        torch.randint(len(sampler.goal_pool), (n, m), generator=g, out=self._reset_fallback)

    def _launch_draws(self) -> None:
        """Step 2's torch draws, on a branch beside the physics (they read nothing the physics writes); joined by
        :meth:`_launch_task` before its first kernel reads them."""
        with self._draws.fork():
            self._draw()

    def _launch_task(self, out: _Outputs, slot: int) -> None:
        """Steps 3-5 (task kernels, resets) on the current streams, reading clock row ``slot``, after
        :meth:`_launch_draws`. The torch draws come in the torch step's order: reached goals (``_end_step``), then the
        autoreset's (``_reset_envs``: start, goals); the reset-mode terms draw in their own kernel, the sensor and
        latency models in the task kernels. The reset firing runs on a branch beside the reset and observation
        kernels (it writes the model's per-world rows, which only the next step's physics reads)."""
        env = self.env
        sim = env.sim
        st, delay = self._sim_arrays()
        a = self._wp
        clock, clock_next = a["clock"][slot], a["clock"][slot ^ 1]
        self._draws.join()
        m = sim.model
        wp.launch(
            ktask.trajectory_step, dim=env.num_envs, device=sim.device,
            inputs=[self._task, self._sampler, m.tiles, m.collision, a["goal_pool"], a["start_pool"], st.pos, st.vel,
                    st.acc, st.flags_any, sim._nonfinite, clock, a["key"], a["step_u"], a["step_fallback"],
                    a["start_index"], a["reset_u"], a["reset_fallback"], self._sensor, a["goals"], a["num_steps"],
                    a["last_goal_step"], a["collected"], sim._init_pos, sim._init_quat, sim._reset_mask, delay],
            outputs=out.step_outputs,
        )
        # the finished worlds' reset-mode randomisation (the kernel reads the device mask)
        if env.randomizer is not None:
            with self._firing.fork():
                env.randomizer.reset_in_step(out.done)
        sim._launch_reset()
        wp.launch(
            ktask.trajectory_obs, dim=env.num_envs, device=sim.device,
            inputs=[self._task.learn_jerk, st.pos, st.vel, st.acc, a["goals"], self._sensor, clock, a["key"],
                    out.step_outputs[-1], *out.step_outputs[:3], clock_next],
            outputs=out.obs_wp,
        )
        if env.randomizer is not None:
            self._firing.join()

    def _launch_eager(self, out: _Outputs, slot: int) -> None:
        env = self.env
        with env.sim._on_stream():
            self._launch_draws()
        env.sim.step(env.num_cycles)
        with env.sim._on_stream():
            self._launch_task(out, slot)

    def _capture(self, out: _Outputs, slot: int) -> RecordedGraph:
        """Record steps 1-5 as one CUDA graph on a side stream (:func:`~magwarp.envs.step_graph.record_cuda_graph`)."""
        env, sim = self.env, self.env.sim

        def launches() -> None:
            self._launch_draws()
            sim._launch_step(env.num_cycles)
            self._launch_task(out, slot)

        return record_cuda_graph(launches, env.device, generators=(env.sampler.generator,))

    def _sync_state(self) -> None:
        """Host-side bookkeeping that needs no device sync: new pools after a reseed, the step count after eager
        steps, and graphs recorded against arrays the simulator has since replaced."""
        env, sampler = self.env, self.env.sampler
        if sampler.goal_pool is not self._pool_sources[0] or sampler.start_pool is not self._pool_sources[1]:
            self._goal_pool.copy_(sampler.goal_pool)
            self._start_pool.copy_(sampler.start_pool)
            self._pool_sources = (sampler.goal_pool, sampler.start_pool)
        host = (env._step_count, env._step_count - env.draw_clock.base)
        if self._clock_host != host:  # eager steps or a reseed since the last fused step: set both rows
            self._clock[:, 0].fill_(host[0])
            self._clock[:, 1].fill_(host[1])
            self._clock_host = host
        sim = env.sim
        key = (id(sim._fused_kernel), id(sim._advance_kernel), id(sim._delay), id(sim._prev_cmd), id(sim.state),
               sim._fused, *(id(getattr(sim.model, k)) for k in ("body", "radius", "half_size", "margins")))
        if key != self._graph_key:
            self._graphs = [None, None]
            self._graph_key = key
            self._cmd = sim.cmd

    def step(self, action: torch.Tensor):
        """One env step for a checked float32 action ``[num_envs, num_movers * 2]``; the step's returns."""
        env = self.env
        self._sync_state()
        self._cmd.copy_(action.reshape(self._cmd.shape))
        slot = self._slot
        out = self._outputs[slot]
        if not self.graph:
            self._launch_eager(out, slot)
        elif self._graphs[slot] is None:
            self._launch_eager(out, slot)  # loads the kernels; the graph is recorded after this real step
            try:
                self._graphs[slot] = self._capture(out, slot)
            except (RuntimeError, AttributeError) as e:  # e.g. no generator registration: the same kernels, eager
                import warnings

                warnings.warn(f"TrajectoryPlanningEnv: the step could not be captured as a CUDA graph ({e}); it runs "
                              "the same kernels eagerly (graph=False)", RuntimeWarning, stacklevel=3)
                self.graph = self.env._graph = False
                self.env._replace_generator()  # the failed capture may keep the old one registered
        else:
            for callback in env.sim._step_callbacks:  # as sim.step runs them (interval randomisation terms)
                callback()
            self._graphs[self._slot].graph.replay()
        self._slot ^= 1
        env._step_count += 1
        self._clock_host = (env._step_count, env._step_count - env.draw_clock.base)
        return out.returns(env.max_episode_steps is not None)

