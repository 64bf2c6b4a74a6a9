"""The trajectory-planning env's fused step (magwarp.envs.trajectory_fused): the same results as the torch step, bit
for bit, for the same seed and actions, with autoresets and goal resamples; on CUDA as one captured graph."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
import warp as wp

from magwarp.envs.sim2real import SensorConfig
from magwarp.envs.trajectory import TrajectoryPlanningEnv

HOLE = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]])

#: every kind of randomisation term: the preset (reset mode, body fields, a known payload), startup, targets, an
#: unknown off-axis payload, collision sizes, and an interval term
TERMS = ["sim2real",
         {"field": "mover_inertia", "dist": {"uniform": [0.9, 1.1]}, "op": "scale", "mode": "startup"},
         {"field": "j_max", "dist": {"uniform": [0.9, 1.0]}, "op": "scale", "mode": "interval", "interval_steps": 7},
         {"field": "collision_radius", "dist": {"gaussian": [-0.003, 0.002], "clip": [-0.006, 0.0]}, "op": "add",
          "targets": [0, 2]},
         {"field": "collision_margin", "dist": {"uniform": [0.0, 0.004]}}]
SENSORS = {"pos_bias": [0.001, -0.002], "pos_bias_std": 0.001, "vel_bias_std": 0.01, "pos_noise_std": 0.0005,
           "vel_noise_std": 0.005, "dropout_prob": 0.2}


def full_randomisation(terms: list, **sensors) -> dict:
    preset = [t for t in terms if isinstance(t, str)]
    rest = [t for t in terms if not isinstance(t, str)]
    from magwarp.envs.randomization import PRESETS

    terms = [*(u for name in preset for u in PRESETS[name]["planar"]), *rest]
    return dict(randomization=terms, actuation={"latency_range": [0, 5]}, sensors={**SENSORS, **sensors})


CONFIGS = {
    "default": {},
    "jerk_episode_cut_latency": dict(learn_jerk=True, max_episode_steps=9, actuation={"latency_range": [1, 7]}),
    "box_hole_no_timeout": dict(layout=HOLE, num_movers=2, collision_shape="box", timeout_steps=None),
    "randomised_sensors": full_randomisation(TERMS),
    "jerk_randomised_box_sensors": dict(learn_jerk=True, collision_shape="box", max_episode_steps=12,
                                        **full_randomisation(["sim2real"], pos_bias=0.0, vel_bias=[0.01, 0.0],
                                                             vel_bias_std=0.0, pos_noise_std=0.0)),
    "std_noise": dict(std_noise=1e-3),
}


def assert_same(x, y, where: str) -> None:
    if isinstance(x, (tuple, list)):
        assert len(x) == len(y), where
        for i, (u, v) in enumerate(zip(x, y)):
            assert_same(u, v, f"{where}[{i}]")
    elif isinstance(x, dict):
        assert list(x) == list(y), f"{where}: keys {list(x)} != {list(y)}"
        for k in x:
            assert_same(x[k], y[k], f"{where}[{k!r}]")
    else:
        assert x.dtype == y.dtype and x.shape == y.shape, \
            f"{where}: {x.dtype}{tuple(x.shape)} != {y.dtype}{tuple(y.shape)}"
        assert x.device == y.device, where
        bad = (x != y) & ~(x.isnan() & y.isnan()) if x.is_floating_point() else x != y
        assert not bool(bad.any()), f"{where}: differs at {bad.nonzero()[:4].tolist()}"


def twin_envs(device: str, **kwargs):
    kw = {"num_envs": 24, "layout": "B0", "device": device, "seed": 11, **kwargs}
    eager, fused = TrajectoryPlanningEnv(fused=False, **kw), TrajectoryPlanningEnv(**kw)
    assert eager.step_path.startswith("eager")
    return eager, fused


def run_twins(eager, fused, steps: int, seed: int, policy=None) -> dict[str, int]:
    """Step both envs with the same actions (random, or ``policy`` on the eager env's observation) and compare every
    return; counts of resets and reached goals."""
    gen = torch.Generator(device=eager.device).manual_seed(seed)
    obs_e, _ = eager.reset(seed=seed)
    obs_f, _ = fused.reset(seed=seed)
    assert_same(obs_e, obs_f, "reset")
    limit = float(eager.single_action_space.high[0])
    counts = {"resets": 0, "goals": 0}
    for t in range(steps):
        if policy is None:
            act = (2 * torch.rand((eager.num_envs, *eager.single_action_space.shape), generator=gen,
                                  device=eager.device) - 1) * limit
        else:
            act = policy(obs_e)
        out_e, out_f = eager.step(act), fused.step(act.clone())
        assert_same(out_e, out_f, f"step {t}")
        obs_e = out_e[0]
        counts["resets"] += int(out_e[4]["_final_obs"].sum())
        counts["goals"] += int(out_e[4]["goals_reached"].sum())
    assert_same(twin_state(eager), twin_state(fused), "state")
    return counts


def twin_state(env) -> dict:
    """The state both steps must leave alike: task counters, poses, and the drawn delays, biases and model rows."""
    sim, sensors = env.sim, env.sensors
    out = {"goals": env.goals, "num_steps": env.num_steps, "last_goal_step": env.last_goal_step,
           "collected": env.collected_goals, "pos": sim.pos, "radii": sim.radii, "margins": sim.margins}
    if sim.latency_cycles is not None:
        out["delay"] = sim.latency_cycles
    out.update({k: v for k, v in (("pos_bias", sensors.pos_bias), ("vel_bias", sensors.vel_bias)) if v is not None})
    if env.randomizer is not None:
        out.update(env.randomizer.values)
    if sim._mover_params is not None:  # what the body rows are packed from
        out.update({f"param_{k}": v for k, v in sim._mover_params.items()})
    return out


@pytest.mark.parametrize("name", list(CONFIGS))
def test_fused_step_matches_eager_random_actions(name):
    eager, fused = twin_envs("cpu", **CONFIGS[name])
    assert fused.step_path == "fused"
    counts = run_twins(eager, fused, 200, seed=3)
    assert counts["resets"] > 50  # random actions collide often: many autoresets were compared


def test_fused_step_matches_eager_with_goals_reached():
    eager, fused = twin_envs("cpu", timeout_steps=20)
    planner = eager.scripted_policy()
    counts = run_twins(eager, fused, 150, seed=4, policy=planner)
    assert counts["goals"] > 20 and counts["resets"] > 0, counts


@pytest.mark.parametrize("name", ["default", "randomised_sensors"])
def test_fused_step_reseed_and_partial_reset_midway(name):
    eager, fused = twin_envs("cpu", **CONFIGS[name])
    run_twins(eager, fused, 20, seed=1)
    mask = torch.zeros(eager.num_envs, dtype=torch.bool)
    mask[::3] = True
    opts = {"reset_mask": mask, "goals": eager.sampler.goal_pool[:3].tolist()}
    assert_same(eager.reset(options=opts), fused.reset(options=opts), "partial reset")
    gen = torch.Generator().manual_seed(9)
    for t in range(30):
        act = (2 * torch.rand(eager.num_envs, 6, generator=gen) - 1) * 10
        assert_same(eager.step(act), fused.step(act), f"after partial reset, step {t}")
    run_twins(eager, fused, 20, seed=77)  # reset(seed=77) redraws the pools: the fused step copies them in


@pytest.mark.parametrize("name", ["default", "randomised_sensors"])
def test_fused_step_nan_guard_matches_eager(name):
    eager, fused = twin_envs("cpu", **CONFIGS[name])
    run_twins(eager, fused, 5, seed=2)
    gen = torch.Generator().manual_seed(4)
    for t, (world, field) in enumerate([(3, "vel"), (7, "pos"), (3, "vel")]):
        for env in (eager, fused):
            getattr(env.sim, field)[world, 1, 0] = float("nan")  # a world's state turns non-finite
        act = (2 * torch.rand(eager.num_envs, 6, generator=gen) - 1) * 10
        out_e, out_f = eager.step(act), fused.step(act)
        assert_same(out_e, out_f, f"nan step {t}")
        assert bool(out_f[4]["nonfinite"][world]) and bool(out_f[2][world]) and float(out_f[1][world]) == 0.0
        assert int(out_f[4]["nonfinite_step"][world]) == fused._step_count
        assert torch.isfinite(out_f[0]["observation"]).all()  # the world was reset


def test_fused_step_refuses_bad_actions_before_any_change():
    _, env = twin_envs("cpu")
    env.step(torch.zeros(env.num_envs, 6))
    before = [t.clone() for t in (env.sim.pos, env.goals, env.num_steps, env.collected_goals)]
    count = env._step_count
    bad = torch.zeros(env.num_envs, 6)
    bad[5, 1] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        env.step(bad)
    with pytest.raises(ValueError, match="shape"):
        env.step(torch.zeros(env.num_envs, 5))
    with pytest.raises(TypeError, match="floating"):
        env.step(torch.zeros(env.num_envs, 6, dtype=torch.int64))
    after = (env.sim.pos, env.goals, env.num_steps, env.collected_goals)
    assert all(torch.equal(a, b) for a, b in zip(before, after))
    assert env._step_count == count


def test_step_path_choice():
    env = TrajectoryPlanningEnv(4, device="cpu")
    assert env.step_path == "fused"
    assert TrajectoryPlanningEnv(4, device="cpu", std_noise=1e-5).step_path == "fused"
    assert TrajectoryPlanningEnv(4, device="cpu", sensors=SensorConfig(dropout_prob=0.1)).step_path == "fused"
    assert TrajectoryPlanningEnv(4, device="cpu", **full_randomisation(TERMS)).step_path == "fused"
    assert TrajectoryPlanningEnv(4, device="cpu", autoreset=False).step_path == "eager (autoreset=False)"
    from magwarp.metrics import Metrics

    Metrics(env)
    assert env.step_path == "eager (benchmark metrics)"


def test_sensor_draws_match_when_the_step_path_switches_midway():
    """The sim2real models' counter-based draws follow the env's step count and reseeds on either path: an env that
    switches between the fused and the torch step (its device clock re-set from the host count) stays bit for bit with
    a torch-step twin, dropped readings, noise, biases and delays included."""
    kw = dict(max_episode_steps=4, actuation={"latency_range": [0, 9]},
              sensors={**SENSORS, "dropout_prob": 0.5})
    eager, fused = twin_envs("cpu", **kw)
    gen = torch.Generator().manual_seed(2)
    assert_same(eager.reset(seed=4), fused.reset(seed=4), "reset")
    for t in range(16):
        fused.fused = t not in range(5, 9)
        assert fused.step_path == ("fused" if fused.fused else "eager (fused=False)")
        act = (2 * torch.rand(eager.num_envs, 6, generator=gen) - 1) * 10
        assert_same(eager.step(act), fused.step(act), f"step {t}")
        if t == 11:  # a reseed midway: the clock counts from it on both
            assert_same(eager.reset(seed=9), fused.reset(seed=9), "reseed")
    assert_same(twin_state(eager), twin_state(fused), "state")


def test_fused_outputs_stay_valid_through_the_next_step():
    env = TrajectoryPlanningEnv(8, device="cpu", seed=2)
    env.reset(seed=2)
    first = env.step(torch.full((8, 6), 3.0))
    kept = torch.utils._pytree.tree_map(torch.clone, first)
    second = env.step(torch.full((8, 6), -3.0))
    assert_same(first, kept, "step t after step t+1")
    assert second[0]["observation"].data_ptr() != first[0]["observation"].data_ptr()


@pytest.mark.skipif(not (torch.cuda.is_available() and wp.is_cuda_available()), reason="needs a CUDA GPU")
@pytest.mark.parametrize("name", list(CONFIGS))
def test_graph_step_matches_eager_on_cuda(name):
    eager, fused = twin_envs("cuda:0", **CONFIGS[name])
    assert fused.step_path == "fused graph"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # a capture that falls back to eager launches fails here
        run_twins(eager, fused, 200, seed=3)
        run_twins(eager, fused, 100, seed=5, policy=eager.scripted_policy())  # reseeded: pools copied, graph replayed
    assert fused.step_path == "fused graph" and fused._fused_step._graphs[0] is not None
    # the fused step without a graph, against a fresh eager twin (randomisation's startup draws and interval-term count
    # belong to an env's life, so a used env and a new one differ even after the same reset seed)
    eager, nograph = twin_envs("cuda:0", **CONFIGS[name], graph=False)
    assert nograph.step_path == "fused"
    run_twins(eager, nograph, 50, seed=6)


def test_fused_step_first_built_in_inference_mode():
    """A training loop may take the first step under torch.inference_mode: later steps outside it still work."""
    env = TrajectoryPlanningEnv(4, device="cpu")
    with torch.inference_mode():
        env.step(torch.zeros(4, 6))
    obs = env.step(torch.ones(4, 6))[0]
    assert torch.isfinite(obs["observation"]).all()


def test_subclass_overriding_a_task_hook_keeps_the_torch_step():
    class Shaped(TrajectoryPlanningEnv):
        def compute_reward(self, achieved_goal, desired_goal, info):
            return super().compute_reward(achieved_goal, desired_goal, info) * 0.5

    env = Shaped(4, device="cpu")
    assert env.step_path == "eager (Shaped overrides compute_reward)"
    reward = env.step(torch.zeros(4, 6))[1]
    assert torch.equal(reward, torch.full((4,), -0.5))
