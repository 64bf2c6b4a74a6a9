"""magwarp/CoopPushResidual-v0: a zero correction is the scripted baseline exactly, a correction adds
``residual_scale * action`` to it, bad options are refused, the env passes the Gymnasium and PettingZoo checks, and
PPO's preset starts the actor at the baseline."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import magwarp  # noqa: F401 - registers the ids
from magwarp.envs.coop_push import CoopPushEnv
from magwarp.envs.coop_push_residual import CoopPushResidualEnv
from magwarp.envs.push import PushEnv


@pytest.fixture
def applied(monkeypatch):
    """What each env hands to the physics, per step: ``applied[id(env)]`` lists the actions."""
    log: dict[int, list[torch.Tensor]] = {}
    apply = PushEnv._apply_action

    def record(self, action):
        log.setdefault(id(self), []).append(action.clone())
        apply(self, action)

    monkeypatch.setattr(PushEnv, "_apply_action", record)
    return log


def _pair(**residual_options):
    opts = dict(device="cpu", seed=3, max_episode_steps=12)
    return CoopPushEnv(num_envs=3, **opts), CoopPushResidualEnv(num_envs=3, **opts, **residual_options)


def test_zero_correction_is_the_scripted_baseline(applied):
    plain, residual = _pair()
    scripted = plain.scripted_policy()
    obs, _ = plain.reset(seed=4)
    obs_r, _ = residual.reset(seed=4)
    zero = residual.scripted_policy()(obs_r)  # the residual env's own baseline: the zero correction
    assert torch.equal(zero, torch.zeros(3, 4))
    ended = torch.zeros(3, dtype=torch.bool)
    for _ in range(15):  # through an autoreset (12-step episodes)
        obs, reward, terminated, truncated, _ = plain.step(scripted(obs))
        obs_r, reward_r, terminated_r, truncated_r, _ = residual.step(zero)
        for key in obs:
            assert torch.equal(obs_r[key], obs[key]), key
        assert torch.equal(reward_r, reward) and torch.equal(terminated_r, terminated)
        assert torch.equal(truncated_r, truncated)
        ended |= truncated | terminated
    assert ended.all()
    ours, theirs = applied[id(residual)], applied[id(plain)]
    assert len(ours) == len(theirs) == 15
    assert all(torch.equal(a, b) for a, b in zip(ours, theirs))
    assert any(a.abs().max() > 1.0 for a in theirs)  # the baseline acts (the test compares real pushes)


def test_a_correction_adds_its_scaled_action_to_the_baseline(applied, rng):
    plain, residual = _pair(residual_scale=0.3)
    scripted = plain.scripted_policy()
    obs, _ = plain.reset(seed=5)
    residual.reset(seed=5)
    for _ in range(5):  # the same states while the correction is zero
        obs, *_ = plain.step(scripted(obs))
        residual.step(torch.zeros(3, 4))
    # one corrected step from the same state: what reaches the physics is the baseline's plus 0.3 x the action
    a = torch.as_tensor(rng.uniform(-10.0, 10.0, (3, 4)), dtype=torch.float32)  # the action space's range
    plain.step(scripted(obs))
    residual.step(a)
    diff = applied[id(residual)][-1] - applied[id(plain)][-1]
    torch.testing.assert_close(diff, 0.3 * a, rtol=0, atol=1e-5)
    assert diff.abs().max() <= 0.3 * 10.0 + 1e-5  # the correction's range: residual_scale x a_max
    assert residual.single_action_space == plain.single_action_space


@pytest.mark.parametrize("bad", [0.0, -0.5, 2.5, float("nan"), True, "0.5"])
def test_bad_residual_scales_are_refused(bad):
    with pytest.raises(ValueError, match="residual_scale"):
        CoopPushResidualEnv(num_envs=1, device="cpu", residual_scale=bad)


def test_bad_baseline_options_are_refused():
    with pytest.raises(TypeError, match="baseline_options"):
        CoopPushResidualEnv(num_envs=1, device="cpu", baseline_options=[1.2])
    with pytest.raises(TypeError, match="bogus"):
        CoopPushResidualEnv(num_envs=1, device="cpu", baseline_options={"bogus": 1.0})
    with pytest.raises(ValueError, match="learn_jerk"):
        CoopPushResidualEnv(num_envs=1, device="cpu", learn_jerk=True)


def test_gymnasium_check_env():
    from gymnasium.utils.env_checker import check_env

    env = gym.make("magwarp/CoopPushResidual-v0", device="cpu")
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    assert obs["observation"].shape == (14,)
    assert env.action_space.shape == (4,) and env.action_space.high[0] == pytest.approx(10.0)
    env.close()


def test_pettingzoo_parallel_api():
    from pettingzoo.test import parallel_api_test

    from magwarp.envs.adapters import MagwarpParallelEnv

    pz = MagwarpParallelEnv(CoopPushResidualEnv, device="cpu", max_episode_steps=20)
    parallel_api_test(pz, num_cycles=30)
    assert pz.possible_agents == ["mover_0", "mover_1"]
    obs, _ = pz.reset(seed=1)
    assert obs["mover_0"].shape == (16,)
    pz.close()


def test_ppo_preset_starts_the_actor_at_the_baseline():
    from magwarp.training import ppo
    from magwarp.training.paper import PAPER_RUNS

    run = PAPER_RUNS["coop_push_residual"]
    assert run.env_id == "magwarp/CoopPushResidual-v0" and run.algo == "ppo"
    args = ppo.resolve_args(ppo.parse_args(["--env-id", run.env_id, "--device", "cpu", "--minutes", "1"]))
    assert (args.actor_init, args.critic_warmup, args.init_log_std) == ("zero", 10, -2.3)  # its row, not "Push"'s
    agent = ppo.Agent(14, 4, [32, 32], args.init_log_std, actor_init=args.actor_init)
    mean, _ = agent.mean_std(torch.as_tensor(np.random.default_rng(0).normal(size=(5, 14)), dtype=torch.float32))
    assert torch.equal(mean, torch.zeros(5, 4))
    args = ppo.resolve_args(ppo.parse_args(["--env-id", "magwarp/CoopPush-v0", "--device", "cpu", "--minutes", "1"]))
    assert args.actor_init == "orthogonal"
    with pytest.raises(ValueError, match="actor_init"):
        ppo.Agent(14, 4, [32], -1.0, actor_init="ones")


def test_eval_refuses_a_residual_policy_on_the_base_env(tmp_path):
    from magwarp.evaluate import EvalError, load_policy
    from magwarp.training.common import RunningMeanStd
    from magwarp.training.policy import save_policy

    path = str(tmp_path / "policy.pt")
    save_policy(path, torch.nn.Linear(18, 4), RunningMeanStd(18, "cpu"), torch.full((4,), 10.0), squash="clip",
                env_id="magwarp/CoopPushResidual-v0")
    plain, residual = _pair()
    assert load_policy(path, residual)(residual.reset(seed=0)[0]).shape == (3, 4)
    with pytest.raises(EvalError, match="corrections to that env's scripted baseline"):
        load_policy(path, plain)
