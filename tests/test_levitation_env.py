"""magwarp/Levitation-v0: coil currents drive a free 6-DoF mover; the PD baseline through the commutation holds it
and reaches setpoints; the actuator's wrench is Gamma i with the currents held at their limits."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from magnetics_helpers import coarse_model, magnetics_cache  # noqa: F401  (tests/ is on sys.path; a fixture)

import magwarp  # noqa: F401  (registers the ids)
from magwarp.envs.levitation import LevitationEnv
from magwarp.policies.levitation import LevitationPD

# A coarse table over the env's gaps (2-6 mm): about a second to build on a CPU.
MAG = coarse_model()


def test_check_env_and_make_vec():
    from gymnasium.utils.env_checker import check_env

    env = gym.make("magwarp/Levitation-v0", magnetics=MAG, device="cpu")
    check_env(env.unwrapped, skip_render_check=True)
    vec = gym.make_vec("magwarp/Levitation-v0", num_envs=3, magnetics=MAG, device="cpu")
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (3, 19) and vec.single_action_space.shape == (vec.actuator.slots,)
    ids = vec.coil_ids
    assert ids.shape == (3, vec.actuator.slots) and (ids >= 0).sum(1).min() >= 20
    hover = gym.make_vec("magwarp/LevitationHover-v0", num_envs=2, magnetics=MAG, device="cpu")
    hover.reset(seed=0)
    assert hover.task == "hover" and hover.errors()[0].max() == 0.0  # the setpoint is the start pose
    wrench = gym.make_vec("magwarp/LevitationWrench-v0", num_envs=2, magnetics=MAG, device="cpu")
    assert wrench.single_action_space.shape == (6,)


@pytest.mark.parametrize("action", ["currents", "wrench"])
def test_pd_baseline_reaches_setpoints(action):
    env = LevitationEnv(4, magnetics=MAG, action=action, device="cpu", seed=3)
    policy = LevitationPD(env)
    obs, _ = env.reset(seed=1)
    pos0, _ = env.errors()
    assert pos0.min() > 1e-3  # setpoints lie millimetres away
    for _ in range(150):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        assert not terminated.any()
    pos_err, rot_err = env.errors()
    assert pos_err.max() < 1e-4 and rot_err.max() < 5e-3, (pos_err, rot_err)
    loss = info["copper_loss"]
    assert torch.all(loss > 10.0) and torch.all(loss < 500.0), loss  # hovering costs tens of watts
    assert torch.all(reward > -0.5) and torch.all(env.energy > 150 * 1e-3 * 10.0)


def test_no_current_falls_and_fails():
    env = LevitationEnv(2, magnetics=MAG, device="cpu", seed=0)
    env.reset(seed=0)
    zero = torch.zeros((2, *env.single_action_space.shape))
    for k in range(60):
        obs, reward, terminated, truncated, info = env.step(zero)
        if terminated.all():
            break
    assert terminated.all() and torch.all(reward == env.failure_reward) and k > 3  # it fell (3 mm take ~25 ms)
    assert torch.all(info["copper_loss"] == 0.0)


def test_actuator_wrench_is_gamma_times_held_currents(rng):
    """Random currents, some beyond the limits: the realised wrench is Gamma i with i held at +-limit, the loss
    sum R i^2, over the window the table model finds at the cycle's start pose."""
    env = LevitationEnv(3, magnetics=MAG, device="cpu", seed=0)
    env.reset(seed=int(rng.integers(1 << 30)))
    act = env.actuator
    pos = env.sim.pos[:, 0].numpy().astype(np.float64)
    quat = env.sim.quat[:, 0].numpy().astype(np.float64)
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    a = rng.uniform(-1.5, 1.5, (3, act.slots)).astype(np.float32)
    env.actuator.currents.copy_(torch.as_tensor(a * env.current_limit)[:, None])
    env.sim.step(1)
    ids, gamma, _ = act.model.columns(*act.model.as_arrays(pos=pos, quat=quat))
    ids, gamma = ids.numpy(), gamma.numpy().astype(np.float64)
    held = np.clip(a * env.current_limit, -env.current_limit, env.current_limit) * (ids >= 0)
    want = np.einsum("msk,ms->mk", gamma, held)
    np.testing.assert_allclose(act.wrench[:, 0].numpy(), want, rtol=1e-4, atol=1e-4, err_msg=str(rng))
    r = act.model.coilset.resistance[0]
    np.testing.assert_allclose(act.loss[:, 0].numpy(), r * (held ** 2).sum(1), rtol=1e-5, err_msg=str(rng))
    sat = act.saturated[:, 0].numpy().astype(bool)
    assert np.array_equal(sat, (np.abs(a) > 1.0) & (ids >= 0)), rng
    np.testing.assert_array_equal(act.applied_currents[:, 0].numpy(), held)


@pytest.mark.parametrize("env_id", ["magwarp/LevitationWrench-v0", "magwarp/LevitationResidual-v0"])
def test_overflowing_actions_are_refused_without_state_change(env_id):
    """A finite float32 share such as 3e38 overflows once scaled to newtons: refused by name, the state kept (the
    fuzz test found a NaN copper loss in ``info`` from one)."""
    env = gym.make_vec(env_id, num_envs=2, magnetics=MAG, device="cpu")
    env.reset(seed=0)
    vec = env.unwrapped if hasattr(env, "unwrapped") else env
    pos = vec.sim.pos.clone()
    action = np.zeros((2, *env.single_action_space.shape), np.float32)
    action[1, 2] = 3e38
    with pytest.raises(ValueError, match=r"index \[1, 2\] is 3\.0\d*e\+38"):
        env.step(action)
    assert torch.equal(vec.sim.pos, pos)
    action[1, 2] = vec.MAX_ACTION_SHARE  # the largest accepted share steps finitely
    obs, reward, _, _, info = env.step(action)
    assert torch.isfinite(torch.as_tensor(obs)).all() and torch.isfinite(info["copper_loss"]).all()


def test_bad_options_are_refused():
    with pytest.raises(ValueError, match="'lift'"):
        LevitationEnv(1, task="lift", magnetics=MAG, device="cpu")
    with pytest.raises(ValueError, match="dt"):
        LevitationEnv(1, dt=-1.0, magnetics=MAG, device="cpu")
    with pytest.raises(ValueError, match="setpoint_gap"):
        LevitationEnv(1, setpoint_gap=(0.003, 1e40), magnetics=MAG, device="cpu")
    with pytest.raises(ValueError, match="pos_scale"):
        LevitationEnv(1, pos_scale=1e-45, magnetics=MAG, device="cpu")
    with pytest.raises(TypeError, match="MagneticModel"):
        LevitationEnv(1, magnetics="magnetic", device="cpu")
