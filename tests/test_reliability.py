"""Issue 25: non-finite and overflowing inputs are refused before any state changes, physical limits are named,
unclear errors are clear, seeding follows the reset seed, and the NaN guard flags (and can dump) any world whose
state turns non-finite."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import numpy as np
import pytest
import torch

from magwarp._checks import STABLE_HW, as_count, as_seed, device_name, stiffness_limit
from magwarp.layout import Layout, LayoutError, MoverSpec
from magwarp.sim import Simulator

NAN, INF = float("nan"), float("inf")


@pytest.fixture(scope="module")
def b0():
    from magwarp.envs.trajectory import TrajectoryPlanningEnv

    return TrajectoryPlanningEnv(4, "B0", device="cpu", seed=1)


def _snapshot(env) -> dict[str, torch.Tensor]:
    sim = env.sim
    return {"pos": sim.pos.clone(), "vel": sim.vel.clone(), "goals": env.goals.clone(),
            "steps": env.num_steps.clone(), "rng": env._generator.get_state().clone()}


def _assert_same(before, after):
    for k, v in before.items():
        assert torch.equal(v, after[k]), k


# ---------------------------------------------------------------------------------------------------- NaN / overflow
@pytest.mark.parametrize("action", [
    torch.full((4, 6), 1e40, dtype=torch.float64),  # finite in float64, inf in float32
    torch.full((4, 6), -3.5e38, dtype=torch.float64),
    torch.tensor([[0.0] * 5 + [NAN]] * 4),
    torch.tensor([[INF] + [0.0] * 5] * 4),
])
def test_vec_env_refuses_actions_not_finite_in_float32_without_state_change(b0, action):
    b0.reset(seed=3)
    before = _snapshot(b0)
    with pytest.raises(ValueError, match=r"non-finite.*float32.*index \[0, \d\]"):
        b0.step(action)
    _assert_same(before, _snapshot(b0))
    obs, *_ = b0.step(torch.zeros(4, 6))
    assert all(torch.isfinite(v).all() for v in obs.values())


def test_single_env_refuses_overflowing_actions_and_bad_seeds():
    import gymnasium as gym

    import magwarp  # noqa: F401

    env = gym.make("magwarp/TrajectoryPlanningB0-v0", device="cpu").unwrapped
    env.reset(seed=0)
    pos = env.vec.sim.pos.clone()
    for value in (1e40, -1e39, NAN, INF):
        with pytest.raises(ValueError, match="non-finite"):
            env.step(np.full(6, value, dtype=np.float64))
    assert torch.equal(env.vec.sim.pos, pos)
    with pytest.raises(TypeError, match="action must be an array of numbers"):
        env.step(["a"] * 6)
    for seed, exc in (("x", TypeError), (2**64, ValueError), (-1, ValueError), (1.5, TypeError)):
        with pytest.raises(exc, match=r"seed must be None or an integer in \[0, 2\*\*64\)"):
            env.reset(seed=seed)
    assert torch.equal(env.vec.sim.pos, pos)


@pytest.mark.parametrize("seed, exc", [("x", TypeError), (2**64, ValueError), (-1, ValueError), (True, TypeError),
                                       (2.0, TypeError)])
def test_vec_env_reset_seed_is_checked(b0, seed, exc):
    before = _snapshot(b0)
    with pytest.raises(exc, match="seed must be None or an integer"):
        b0.reset(seed=seed)
    _assert_same(before, _snapshot(b0))


def test_largest_seed_is_accepted(b0):
    obs, _ = b0.reset(seed=2**64 - 1)
    assert torch.isfinite(obs["achieved_goal"]).all()


@pytest.mark.parametrize("kwargs, message", [
    ({"gravity": NAN}, "gravity must be a finite number"),
    ({"gravity": INF}, "gravity must be a finite number"),
    ({"gravity": "down"}, "gravity must be a finite number"),
    ({"dt": NAN}, "dt must be a finite number"),
    ({"a_max": -INF}, "a_max must be a finite number"),
    ({"stiffness_lin": (1, 1, NAN)}, "stiffness_lin must be 3 finite"),
    ({"num_worlds": NAN}, "num_worlds must be an integer >= 1, got nan"),
    ({"num_worlds": 2.5}, "num_worlds must be an integer >= 1, got 2.5"),
    ({"num_worlds": "3"}, "num_worlds must be an integer >= 1, got '3'"),
    ({"num_movers": 1.5}, "num_movers must be an integer >= 1, got 1.5"),
    ({"max_pairs": NAN}, "max_pairs must be an integer"),
    ({"force_aux_dim": 0.5}, "force_aux_dim must be an integer"),
    ({"mover": "big"}, "mover must be a MoverSpec"),
])
def test_simulator_refuses_non_finite_and_non_integral_arguments(kwargs, message):
    base = {"layout": np.ones((2, 2)), "num_movers": 1, "device": "cpu"}
    with pytest.raises((ValueError, TypeError), match=message):
        Simulator(**{**base, **kwargs})


@pytest.mark.parametrize("n", [NAN, 2.5, "2", 0, -1, None])
def test_step_counts_are_integers(n):
    sim = Simulator(np.ones((2, 2)), 1, device="cpu")
    pos = sim.pos.clone()
    with pytest.raises((ValueError, TypeError), match="num_cycles must be"):
        sim.step(n)
    assert torch.equal(sim.pos, pos)
    sim.step(np.int64(2))  # numpy integers and integral floats are counts
    sim.step(2.0)


def test_simulator_command_overflow_is_refused():
    sim = Simulator(np.ones((2, 2)), 1, 2, device="cpu")
    cmd = torch.zeros(2, 1, 2, dtype=torch.float64)
    cmd[1, 0, 0] = 1e40
    with pytest.raises(ValueError, match=r"non-finite value at index \[1, 0, 0\]"):
        sim.step(1, cmd)
    assert torch.equal(sim.cmd, torch.zeros(2, 1, 2))


@pytest.mark.parametrize("args, message", [
    ((NAN, 2), "num_tiles_x must be an integer >= 1, got nan"),
    ((2.5, 2), "got 2.5"),
    ((2, "3"), "num_tiles_y must be an integer"),
    ((0, 3), "0x3"),
])
def test_layout_grid_counts(args, message):
    with pytest.raises(LayoutError, match=message):
        Layout.grid(*args)


@pytest.mark.parametrize("tiles", [[[1, 1], [1]], [[1, 1], [1, [1]]], [["a", 1]]])
def test_ragged_or_odd_layouts_are_named(tiles):
    with pytest.raises(LayoutError, match="layout must"):
        Layout(tiles)
    with pytest.raises(LayoutError, match="layout must"):
        Simulator(tiles, 1, device="cpu")


@pytest.mark.parametrize("kwargs, message", [
    ({"mass": "heavy"}, r"MoverSpec.mass must be a number, got 'heavy'"),
    ({"mass": None}, r"MoverSpec.mass must be a number"),
    ({"size": (0.1, "b", 0.01)}, r"MoverSpec.size must be a number, got 'b'"),
    ({"size": 3}, r"MoverSpec.size must be a sequence of numbers"),
    ({"hover_gap": NAN}, r"MoverSpec.hover_gap must be >= 0"),
    ({"collision_half_size": ("x", 1)}, r"MoverSpec.collision_half_size must be a number"),
])
def test_mover_spec_errors_name_the_field(kwargs, message):
    with pytest.raises(LayoutError, match=message):
        MoverSpec(**kwargs)


def test_torch_devices_are_accepted_everywhere():
    from magwarp.evaluate import _check_device

    sim = Simulator(np.ones((2, 2)), 1, device=torch.device("cpu"))
    assert sim.torch_device == torch.device("cpu")
    assert _check_device(torch.device("cpu")) == "cpu"
    assert device_name(torch.device("cuda")) == "cuda:0" and device_name(torch.device("cuda", 1)) == "cuda:1"
    assert device_name(sim.device) == "cpu"
    with pytest.raises(TypeError, match="device must be"):
        device_name(3)


def test_checks_helpers():
    assert as_count(np.int32(3), "n") == 3 and as_count(4.0, "n") == 4
    for bad in (True, NAN, INF, 2.5, "3", None, [1]):
        with pytest.raises((TypeError, ValueError), match="n must be an integer"):
            as_count(bad, "n")
    assert as_seed(np.uint64(2**64 - 1)) == 2**64 - 1


# ---------------------------------------------------------------------------------------------------- env kwargs
@pytest.mark.parametrize("kwargs, message", [
    ({"reward_per_step": NAN}, "reward_per_step must be finite"),
    ({"reward_success": INF}, "reward_success must be finite"),
    ({"reward_collision": 1e39}, r"reward_collision must be finite \(in float32\)"),
    ({"threshold_pos": NAN}, "threshold_pos must be finite"),
    ({"safety_margin": NAN}, "safety_margin must be finite"),
    ({"collision_size": INF}, "collision_size must be finite"),
    ({"num_envs": NAN}, "num_envs must be an integer"),
    ({"num_envs": 2.5}, "num_envs must be an integer"),
    ({"num_cycles": 2.5}, "num_cycles must be an integer"),
    ({"num_movers": NAN}, "num_movers must be an integer"),
    ({"timeout_steps": 0.5}, "timeout_steps must be an integer"),
    ({"layout": [[1, 1], [1]], "num_movers": 1}, "layout must be a rectangular"),
    ({"v_max": NAN}, r"v_max must be finite \(in float32\), got nan"),
    ({"seed": "x"}, "seed must be None or an integer"),
])
def test_trajectory_env_refuses_bad_kwargs(kwargs, message):
    from magwarp.envs.trajectory import TrajectoryPlanningEnv

    with pytest.raises((ValueError, TypeError), match=message):
        TrajectoryPlanningEnv(**{"num_envs": 1, "device": "cpu", **kwargs})


@pytest.mark.parametrize("kwargs, message", [
    ({"per_step_penalty": NAN}, "per_step_penalty must be finite"),
    ({"object_width": INF}, "object_width must be finite"),
    ({"object_mass": NAN}, "object_mass must be finite"),
    ({"nconmax": 0}, "nconmax must be >= 1, got 0"),
    ({"njmax": 2.5}, "njmax must be an integer"),
    ({"num_cycles": NAN}, "num_cycles must be an integer"),
    ({"num_envs": 1.5}, "num_envs must be an integer"),
    ({"mover_params": {"size": [1, 1, 0.01]}}, r"mover of size \(2.0, 2.0, 0.02\) m .* does not fit the layout.*"
                                               r"largest half size that fits is 0.140 m"),
    ({"object_width": 2.0}, r"square_box object .* does not fit the layout .* largest that fits reaches 0.300 m"),
    ({"object_ranges": {"width": (0.01, 5.0)}}, r"with object_ranges, the largest\) does not fit"),
    ({"object_type": "cylinder", "object_radius": 0.5}, r"cylinder object \(radius 0.5 m"),
])
def test_push_env_refuses_bad_kwargs_and_impossible_scenes(kwargs, message):
    from magwarp.envs.push import PushEnv

    with pytest.raises((ValueError, TypeError), match=message):
        PushEnv(**{"num_envs": 1, "device": "cpu", **kwargs})


def test_pettingzoo_adapter_names_the_envs_it_serves():
    from magwarp.envs.adapters.pettingzoo import MagwarpParallelEnv
    from magwarp.envs.push import PushBoxEnv

    with pytest.raises(TypeError, match="serves multi-agent envs.*got 'PushBoxEnv'"):
        MagwarpParallelEnv(PushBoxEnv, device="cpu")


# ---------------------------------------------------------------------------------------------------- stiffness limit
def _spectral_radius(hw: float) -> float:
    """Largest |eigenvalue| of one semi-implicit, critically damped step in units of (x, v / w) (numpy reference)."""
    a = hw
    update = np.array([[1 - a * a, a * (1 - 2 * a)], [-a, 1 - 2 * a]])  # x' = x + a u', u' = (1 - 2a) u - a x
    return float(np.abs(np.linalg.eigvals(update)).max())


@pytest.mark.parametrize("factor, stable", [(0.5, True), (0.99, True), (1.01, False), (2.0, False)])
def test_stable_limit_matches_the_update_matrix(factor, stable):
    assert (_spectral_radius(factor * STABLE_HW) < 1.0) == stable


def test_stiffness_above_the_stable_limit_is_refused_and_below_it_stays_finite():
    mass = MoverSpec().mass
    limit = stiffness_limit(mass, 1e-3)
    assert 8.4e5 < limit < 8.6e5  # 1.24 kg at 1 ms
    with pytest.raises(ValueError, match=r"stiffness_lin z = 2e\+06 is unstable at dt = 0.001 s.*stable limit is 8\.5"):
        Simulator(np.ones((2, 2)), 1, device="cpu", stiffness_lin=(1, 1, 2e6))
    with pytest.raises(ValueError, match=r"stiffness_rot yaw = 1e\+06 is unstable"):
        Simulator(np.ones((2, 2)), 1, device="cpu", stiffness_rot=(0.1, 0.1, 1e6))
    # unheld axes are not integrated by the impedance law: any stiffness is accepted there
    Simulator(np.ones((2, 2)), 1, device="cpu", stiffness_lin=(1e9, 1, 100))
    # a shorter cycle raises the limit
    Simulator(np.ones((2, 2)), 1, device="cpu", stiffness_lin=(1, 1, 2e6), dt=5e-4)
    sim = Simulator(np.ones((2, 2)), 1, device="cpu", stiffness_lin=(1, 1, 0.97 * limit))
    sim.set_targets(z=torch.full((1, 1), sim.model.hover_z + 1e-3))
    sim.step(500)
    assert torch.isfinite(sim.pos).all() and abs(float(sim.pos[0, 0, 2]) - sim.model.hover_z - 1e-3) < 1e-4


# ---------------------------------------------------------------------------------------------------- seeding
def test_reset_seed_alone_fixes_the_episode():
    from magwarp.envs.trajectory import TrajectoryPlanningEnv

    a = TrajectoryPlanningEnv(3, "B0", device="cpu", seed=5)
    b = TrajectoryPlanningEnv(3, "B0", device="cpu")
    oa, _ = a.reset(seed=0)
    ob, _ = b.reset(seed=0)
    for k in oa:
        assert torch.equal(oa[k], ob[k]), k
    for _ in range(3):
        act = torch.rand(3, 6) * 4 - 2
        sa, sb = a.step(act), b.step(act)
        assert torch.equal(sa[0]["desired_goal"], sb[0]["desired_goal"])
        assert torch.equal(sa[1], sb[1])
    # a different reset seed gives a different episode
    oc, _ = b.reset(seed=1)
    assert not torch.equal(oa["achieved_goal"], oc["achieved_goal"])


# ---------------------------------------------------------------------------------------------------- NaN guard
def test_guard_kernel_matches_numpy_reference(rng):
    import warp as wp

    from magwarp.kernels.guard import count_step, flag_nonfinite

    W, M = 37, 5
    fields = {"pos": 3, "quat": 4, "vel": 3, "omega": 3}
    host = {k: rng.normal(size=(W, M, d)).astype(np.float32) for k, d in fields.items()}
    for k in host:  # sprinkle NaN / inf into random entries
        mask = rng.random(host[k].shape) < 0.01
        host[k][mask] = rng.choice([np.nan, np.inf, -np.inf], size=int(mask.sum()))
    record = np.where(rng.random(W) < 0.1, 3, -1).astype(np.int32)  # some worlds flagged at an earlier step
    steps = wp.array([6], dtype=wp.int32, device="cpu")
    dtypes = {"pos": wp.vec3, "quat": wp.quat, "vel": wp.vec3, "omega": wp.vec3}
    arrays = {k: wp.array(v, dtype=dtypes[k], device="cpu") for k, v in host.items()}
    out = wp.array(record, dtype=wp.int32, device="cpu")
    wp.launch(count_step, dim=1, inputs=[steps], device="cpu")
    wp.launch(flag_nonfinite, dim=(W, M), inputs=[steps, arrays["pos"], arrays["quat"], arrays["vel"], arrays["omega"],
                                               out],
              device="cpu")
    bad = np.zeros(W, dtype=bool)
    for v in host.values():
        bad |= ~np.isfinite(v).all(axis=(1, 2))
    expected = np.where(record >= 0, record, np.where(bad, 7, -1))
    np.testing.assert_array_equal(out.numpy(), expected, err_msg=str(rng))
    assert steps.numpy()[0] == 7


def test_simulator_guard_flags_the_world_and_step_and_dumps_it(tmp_path):
    sim = Simulator(np.ones((3, 3)), 2, 3, device="cpu", check_inputs=False)
    sim.step(5)
    sim.step(5)
    cmd = torch.zeros(3, 2, 2)
    cmd[1, 0, 1] = NAN  # what check_inputs=False lets through
    sim.step(5, cmd)
    assert sim.nonfinite_step.tolist() == [-1, 3, -1]
    assert sim.nonfinite_worlds() == [(1, 3)]
    sim.step(5, torch.zeros(3, 2, 2))
    assert sim.nonfinite_worlds() == [(1, 3)]  # the first step is kept
    assert sim.steps_taken == 4
    path = sim.dump_state(str(tmp_path / "bug.npz"))
    data = np.load(path)
    assert data["world"].tolist() == [1] and not np.isfinite(data["pos"]).all()
    assert "stiffness_lin" in str(data["params"])
    sim.reset(torch.tensor([False, True, False]))
    assert sim.nonfinite_step.tolist() == [-1, -1, -1] and torch.isfinite(sim.pos).all()


def test_guard_can_be_turned_off():
    sim = Simulator(np.ones((2, 2)), 1, device="cpu", check_inputs=False, nan_guard=False)
    sim.step(2, torch.full((1, 1, 2), NAN))
    assert sim.nonfinite_step.tolist() == [-1] and not torch.isfinite(sim.pos).all()


def test_env_guard_terminates_flags_and_dumps_a_nan_world(tmp_path):
    from magwarp.envs.trajectory import TrajectoryPlanningEnv

    env = TrajectoryPlanningEnv(3, "B0", device="cpu", check_inputs=False, nan_dump=str(tmp_path / "nan"))
    env.reset(seed=0)
    env.step(torch.zeros(3, 6))
    act = torch.zeros(3, 6)
    act[2, 3] = NAN
    with pytest.warns(RuntimeWarning, match=r"world\(s\) \[2\] turned non-finite at step 2"):
        obs, reward, terminated, truncated, info = env.step(act)
    assert info["nonfinite"].tolist() == [False, False, True]
    assert info["nonfinite_step"].tolist() == [-1, -1, 2]
    assert terminated[2] and reward[2] == 0 and torch.isfinite(reward).all()
    assert all(torch.isfinite(v).all() for v in obs.values())  # autoreset replaced the NaN world
    assert not torch.isfinite(info["final_obs"]["achieved_goal"][2]).all()
    data = np.load(tmp_path / "nan.npz")
    assert data["world"].tolist() == [2] and np.isnan(data["action"]).any()
    assert not np.isfinite(data["sim_pos"]).all()
    obs, reward, terminated, truncated, info = env.step(torch.zeros(3, 6))
    assert not info["nonfinite"].any() and not terminated.any()


def test_push_env_guard_reads_the_physics_state():
    from magwarp.envs.push import PushBoxEnv

    env = PushBoxEnv(2, device="cpu")
    env.reset(seed=0)
    env.backend.qvel_t[0, 0] = NAN  # a state gone bad inside the physics (inputs are checked before)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no dump asked for: no warning, no sync
        _, reward, terminated, _, info = env.step(torch.zeros(2, 2))
    assert info["nonfinite"].tolist() == [True, False] and terminated[0] and torch.isfinite(reward).all()
    assert info["nonfinite_step"].tolist() == [1, -1]
    assert torch.isfinite(env.backend.qpos_t).all()  # autoreset replaced the world


# ---------------------------------------------------------------------------------------------------- Warp's noise
def test_no_cuda_driver_warning_on_a_cpu_machine():
    code = ("import magwarp, sys; from magwarp.sim import default_device; d = default_device(); "
            "sys.stderr.write('device=' + d)")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(os.path.dirname(os.path.dirname(__file__))),
                                                         os.environ.get("PYTHONPATH", "")])}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "device=" in res.stderr
    assert "Could not find or load the NVIDIA CUDA driver" not in res.stderr + res.stdout


# ---------------------------------------------------------------------------------------------------- long-fuzz finds
@pytest.mark.parametrize("env_id, kwargs, match", [
    ("magwarp/PushBox-v0", {"learn_jerk": float("nan")}, "learn_jerk must be True or False, got nan"),
    ("magwarp/PushBox-v0", {"use_sparse_pose_reward": "yes"}, "use_sparse_pose_reward must be True or False"),
    ("magwarp/PushBox-v0", {"object_noise": 1e40}, r"object_noise must be finite \(in float32\)"),
    ("magwarp/CoopPush-v0", {"object_mass": float("nan")}, "object_mass must be finite"),
    ("magwarp/CoopPush-v0", {"force_ratio": -1.0}, "force_ratio must be positive"),
    ("magwarp/CoopPush-v0", {"num_movers": 2.5}, "num_movers must be an integer"),
    ("magwarp/TrajectoryPlanningB0-v0", {"learn_jerk": 2}, "learn_jerk must be True or False, got 2"),
])
def test_env_flags_and_values_found_by_the_long_fuzz_profile_are_named(env_id, kwargs, match):
    """Cases the fuzz module's ``local`` profile (HYPOTHESIS_PROFILE=local) found: Python truthiness decided NaN
    flags, 1e40 noise overflowed float32 observations, CoopPush converted a NaN mass to an integer."""
    import gymnasium as gym

    with pytest.raises((TypeError, ValueError), match=match):
        gym.make_vec(env_id, num_envs=1, device="cpu", **kwargs)


def test_a_cycle_shorter_than_a_microsecond_is_refused():
    with pytest.raises(ValueError, match=r"dt must be at least 1e-6 s.*2e-293"):
        Simulator(np.ones((2, 2)), 1, 1, dt=2e-293, device="cpu")


@pytest.mark.parametrize("kwargs, match", [
    ({"a_max": 3.4028235e38}, "a_max must be at most 1e"), ({"gravity": 2.7e38}, "gravity must be at most 1e"),
])
def test_limits_whose_arithmetic_overflows_float32_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Simulator(np.ones((2, 2)), 1, 1, device="cpu", **kwargs)


def test_push_noise_that_overflows_observations_is_refused():
    import gymnasium as gym

    with pytest.raises(ValueError, match="object_noise must be at most 1e"):
        gym.make_vec("magwarp/CoopPush-v0", num_envs=1, device="cpu", object_noise=3.4e38)
