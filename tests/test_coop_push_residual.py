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
    assert (args.actor_init, args.critic_warmup, args.init_log_std) == ("zero", 10, -1.6)  # its row, not "Push"'s
    agent = ppo.Agent(14, 4, [32, 32], args.init_log_std, actor_init=args.actor_init)
    mean, _ = agent.mean_std(torch.as_tensor(np.random.default_rng(0).normal(size=(5, 14)), dtype=torch.float32))
    assert torch.equal(mean, torch.zeros(5, 4))
    args = ppo.resolve_args(ppo.parse_args(["--env-id", "magwarp/CoopPush-v0", "--device", "cpu", "--minutes", "1"]))
    assert args.actor_init == "orthogonal"
    with pytest.raises(ValueError, match="actor_init"):
        ppo.Agent(14, 4, [32], -1.0, actor_init="ones")


def _residual_file(path: str) -> str:
    """A policy file for the residual env whose corrections are not zero (a random linear map, 1 m/s^2 or so)."""
    from magwarp.training.common import RunningMeanStd
    from magwarp.training.policy import save_policy

    torch.manual_seed(0)
    net = torch.nn.Linear(18, 4)
    torch.nn.init.normal_(net.weight, std=0.05)
    save_policy(path, net, RunningMeanStd(18, "cpu"), torch.full((4,), 10.0), squash="clip",
                env_id="magwarp/CoopPushResidual-v0", metadata={"eval_env_kwargs": '{"num_cycles": 40}'})
    return path


def test_the_standalone_policy_acts_on_plain_coop_push_as_in_the_residual_env(tmp_path):
    """write_standalone_policy: baseline + scale x residual in one TorchScript file for CoopPush-v0 observations;
    through autoresets (new goals start new episodes) it steps the plain env exactly as the residual env steps."""
    from magwarp.evaluate import EvalError, load_policy
    from magwarp.training.policy import policy_metadata

    path = _residual_file(str(tmp_path / "policy.pt"))
    plain, residual = _pair(residual_scale=0.5)
    out = str(tmp_path / residual.STANDALONE_POLICY)
    residual.write_standalone_policy(path, out)
    meta = policy_metadata(out)
    assert meta["env_id"] == "magwarp/CoopPush-v0" and meta["residual_env_id"] == "magwarp/CoopPushResidual-v0"
    assert meta["residual_scale"] == 0.5 and meta["eval_env_kwargs"] == '{"num_cycles": 40}'
    trained, standalone = load_policy(path, residual), load_policy(out, plain)
    obs_r, _ = residual.reset(seed=6)
    obs, _ = plain.reset(seed=6)
    for _ in range(15):  # through an autoreset (12-step episodes)
        correction = trained(obs_r)
        assert correction.abs().max() > 0.1  # the residual acts
        obs_r, reward_r, *_ = residual.step(correction)
        obs, reward, *_ = plain.step(standalone(obs))
        for key in obs:
            assert torch.equal(obs[key], obs_r[key]), key
        assert torch.equal(reward, reward_r)
    # a batch of another size starts afresh; a flattened observation is taken as the goal dict
    flat = torch.cat([obs["achieved_goal"], obs["desired_goal"], obs["observation"]], -1)
    module = standalone.module
    assert module(flat[:2]).shape == (2, 4) and torch.isfinite(module(flat)).all()
    from magwarp.training.export import _flat_module

    with pytest.raises(ValueError, match="keeps state between calls"):
        _flat_module(module, None)
    # eval refuses each file on the other env: corrections alone, or the baseline added twice
    with pytest.raises(EvalError, match="corrections to that env's scripted baseline"):
        load_policy(path, plain)
    with pytest.raises(EvalError, match="already adds"):
        load_policy(out, residual)


def test_ppo_writes_the_standalone_policy_beside_its_own(tmp_path):
    from magwarp.training import ppo
    from magwarp.training.policy import policy_metadata

    args = ppo.parse_args(["--env-id", "magwarp/CoopPushResidual-v0", "--env-kwargs", '{"max_episode_steps": 8}',
                           "--device", "cpu", "--seed", "1", "--num-envs", "4", "--num-steps", "4",
                           "--num-minibatches", "1", "--update-epochs", "1", "--hidden", "16", "--critic-warmup", "0",
                           "--total-steps", "32", "--eval-steps", "0", "--out", str(tmp_path), "--no-progress",
                           "--log-every", "1000"])
    ppo.train(args)
    assert policy_metadata(str(tmp_path / "policy.pt"))["env_id"] == "magwarp/CoopPushResidual-v0"
    assert policy_metadata(str(tmp_path / "policy_coop_push.pt"))["env_id"] == "magwarp/CoopPush-v0"
