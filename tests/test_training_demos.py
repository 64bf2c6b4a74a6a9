"""Demonstrations for SAC + HER (:mod:`magwarp.training.demos`): the scripted baseline's transitions in the replay
buffer (seeding and a fixed share of worlds), marked as demonstrations, and the Q-filtered behaviour-cloning term."""

from __future__ import annotations

import csv
from types import SimpleNamespace

import pytest
import torch

from magwarp.training import sac_her
from magwarp.training.demos import ScriptedDemos

TINY_ENV = "magwarp/TrajectoryPlanning-v0"
TINY_KWARGS = '{"layout": [[1, 1, 1], [1, 1, 1], [1, 1, 1]], "num_movers": 1}'


@pytest.fixture(autouse=True)
def one_thread():
    """Small networks: one torch thread is the fastest (and the machine's cores are shared)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def coop():
    from magwarp.envs.coop_push import CoopPushEnv

    env = CoopPushEnv(num_envs=4, device="cpu", seed=3, max_episode_steps=6)
    yield env
    env.close()


def _dims(space) -> dict[str, int]:
    dims = {}
    for k in ("observation", "achieved_goal", "desired_goal"):
        dims[k] = dims["next_" + k] = int(space[k].shape[0])
    return dims


def test_demo_seeding_fills_the_buffer_with_the_scripted_policys_transitions(coop):
    """Seeding (2 episodes of 6 steps): every world acts with the baseline and the buffer holds its actions (in
    learner units), its rewards and next observations, all marked as demonstrations; after it, only the share's
    worlds (the first 2 of 4) act with it and the others keep the learner's actions."""
    scale = torch.as_tensor(coop.single_action_space.high)
    demos = ScriptedDemos(coop, scale, episodes=2, share=0.5)
    assert demos.seed_steps == 12 and demos.worlds == 2 and demos.enabled
    reference = coop.scripted_policy()  # a second instance fed the same observations: the same (stateful) actions
    buf = sac_her.HerReplayBuffer(32, 4, {**_dims(coop.single_observation_space), "action": 4}, ["mover_collision"],
                                  "cpu", track_demos=True)
    obs, _ = coop.reset(seed=5)
    learner_action = torch.full((4, 4), 0.25)
    expected, rewards = [], []
    for step in range(16):
        want = (reference(obs) / scale).clamp(-1, 1)
        action = demos(obs, learner_action, step)
        acting = demos.acting(step)
        if step < 12:
            assert bool(acting.all()) and demos.share_at(step) == 1.0
            torch.testing.assert_close(action, want)
        else:
            assert acting.tolist() == [True, True, False, False] and demos.share_at(step) == 0.5
            torch.testing.assert_close(action[:2], want[:2])
            assert torch.equal(action[2:], learner_action[2:])
        nxt, reward, terminated, truncated, info = coop.step(action * scale)
        buf.add(obs, action, reward, info["final_obs"], terminated, terminated | truncated, info, acting)
        expected.append(action.clone())
        rewards.append(reward.clone())
        obs = nxt
    assert float(torch.stack(expected)[:12].abs().max()) > 0.5  # the baseline really drives the movers
    torch.testing.assert_close(buf.data["action"][:16], torch.stack(expected))
    torch.testing.assert_close(buf.reward[:16], torch.stack(rewards))
    assert bool(buf.demo[:12].all()) and buf.demo[12:16].tolist() == [[True, True, False, False]] * 4
    out = buf.sample(512, 0.5, coop.compute_reward)
    assert set(out["demo"].unique().tolist()) == {0.0, 1.0}
    # a sample is a demonstration exactly when its slot is: the learner's worlds' late steps are not
    demo_actions = out["action"][out["demo"] == 1.0]
    assert demo_actions.shape[0] > 0.6 * 512  # 56 of 64 stored transitions are demonstrations
    with pytest.raises(ValueError, match="demo=\\[num_envs\\]"):
        buf.add(obs, action, reward, info["final_obs"], terminated, terminated, info)


def test_scripted_demos_refuse_bad_options_naming_them(coop):
    scale = torch.as_tensor(coop.single_action_space.high)
    for share in (1.0, -0.1, 0.9):  # 0.9 of 4 worlds rounds to all of them
        with pytest.raises(ValueError, match="share|none to the learner"):
            ScriptedDemos(coop, scale, share=share)
    for episodes in (-1, 1.5, True):
        with pytest.raises(ValueError, match="demo episodes"):
            ScriptedDemos(coop, scale, episodes=episodes)
    off = ScriptedDemos(coop, scale)
    assert not off.enabled and off.policy is None  # no baseline is built when none acts
    action = torch.rand(4, 4)
    assert off(None, action, 0) is action
    plain = SimpleNamespace(num_envs=4, max_episode_steps=10)
    with pytest.raises(ValueError, match="scripted baseline"):
        ScriptedDemos(plain, scale, episodes=1)
    endless = SimpleNamespace(num_envs=4, max_episode_steps=None)
    with pytest.raises(ValueError, match="max_episode_steps"):
        ScriptedDemos(endless, scale, episodes=1)


def _learner(*extra: str) -> sac_her.SacLearner:
    args = sac_her.resolve_args(sac_her.parse_args(["--env-id", TINY_ENV, "--device", "cpu", "--total-steps", "1",
                                                    "--hidden", "32,32", *extra]))
    return sac_her.SacLearner(6, 2, args, torch.device("cpu"))


def _batch(n: int, seed: int, demo: torch.Tensor) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    out = {}
    for k in ("achieved_goal", "desired_goal", "observation"):
        out[k], out["next_" + k] = torch.randn(n, 2, generator=g), torch.randn(n, 2, generator=g)
    out["action"] = torch.rand(n, 2, generator=g) * 2 - 1
    out["reward"] = torch.zeros(n)
    out["terminated"] = torch.zeros(n, dtype=torch.bool)
    out["demo"] = demo.float()
    return out


def test_bc_loss_is_the_q_filtered_squared_error_on_demonstrations():
    torch.manual_seed(0)
    learner = _learner("--demo-bc", "1.0", "--demo-share", "0.5")
    mb = _batch(64, 0, torch.arange(64) % 2 == 0)
    x = learner.norm({k: mb[k] for k in ("achieved_goal", "desired_goal", "observation")})
    with torch.no_grad():
        a, _ = learner.actor(x)
        q_pi = torch.min(*learner.critic(x, a))
        loss = learner._bc_loss(x, mb, q_pi)
        # reference, written out: per sample, both Q heads at the demonstrated action against the policy's sample
        mean = torch.tanh(learner.actor.net(x)[:, :2])
        q1, q2 = learner.critic(x, mb["action"])
        keep = [bool(mb["demo"][i]) and min(float(q1[i]), float(q2[i])) > float(q_pi[i]) for i in range(64)]
        ref = sum(float(((mean[i] - mb["action"][i]) ** 2).sum()) for i in range(64) if keep[i]) / 32
    assert 0 < sum(keep) < 32  # the filter keeps some demonstrations and drops others
    assert float(loss) == pytest.approx(ref, rel=1e-5)
    with torch.no_grad():
        none = learner._bc_loss(x, {**mb, "demo": torch.zeros(64)}, q_pi)
    assert float(none) == 0.0


def test_bc_term_pulls_the_actor_to_the_demonstrated_actions():
    """With rewards all zero the critic has nothing to prefer; the BC term moves the deterministic action onto the
    demonstrations (the same action everywhere), without it the actor stays away from them."""
    gaps = {}
    for weight in ("0", "5.0"):
        torch.manual_seed(1)
        learner = _learner("--demo-bc", weight, "--demo-share", "0.5", "--lr", "5e-3")
        mb = _batch(4 * 64, 2, torch.ones(4 * 64, dtype=torch.bool))
        mb["action"] = torch.tensor([0.6, -0.4]).expand(4 * 64, 2).clone()
        for _ in range(15):
            learner.learn(mb, 4)
        x = learner.norm({k: mb[k] for k in ("achieved_goal", "desired_goal", "observation")})
        with torch.no_grad():
            gaps[weight] = float((learner.actor(x, deterministic=True)[0] - mb["action"]).norm(dim=-1).mean())
    assert gaps["5.0"] < 0.15 < gaps["0"], gaps


def test_sac_trains_with_demonstrations_end_to_end(tmp_path):
    """The options reach the run: the baseline acts in a share of the worlds, the log says how many, the success
    statistics count the learner's worlds; bad combinations fail before anything is built."""
    common = ["--env-id", TINY_ENV, "--env-kwargs", TINY_KWARGS, "--device", "cpu", "--seed", "0", "--num-envs", "8",
              "--batch-size", "64", "--hidden", "32,32", "--learning-starts", "2", "--buffer-steps", "32",
              "--no-progress", "--log-every", "0", "--eval-steps", "0"]
    summary = sac_her.train(sac_her.parse_args([*common, "--out", str(tmp_path), "--total-steps", "160",
                                                "--demo-share", "0.25", "--demo-bc", "1.0"]))
    assert summary["global_step"] == 160
    rows = list(csv.DictReader(open(tmp_path / "progress.csv")))
    assert rows and all(float(r["demo_share"]) == 0.25 for r in rows)
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    assert ckpt["args"]["demo_share"] == 0.25 and ckpt["args"]["demo_bc"] == 1.0
    with pytest.raises(ValueError, match="--demo-bc 1.0 clones demonstrations"):
        sac_her.train(sac_her.parse_args([*common, "--out", str(tmp_path / "x"), "--total-steps", "8",
                                          "--demo-bc", "1.0"]))
    with pytest.raises(ValueError, match="--demo-bc must be"):
        sac_her.train(sac_her.parse_args([*common, "--out", str(tmp_path / "x"), "--total-steps", "8",
                                          "--demo-bc", "nan", "--demo-share", "0.5"]))
    with pytest.raises(ValueError, match="max_episode_steps"):  # trajectory planning's episodes have no length
        sac_her.train(sac_her.parse_args([*common, "--out", str(tmp_path / "x"), "--total-steps", "8",
                                          "--demo-episodes", "1"]))
