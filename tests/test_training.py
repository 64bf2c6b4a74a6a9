"""Training: PPO learns a tiny task on the CPU (fixed seed, a few seconds), and the saved files follow the policy
file contract of :mod:`magwarp.training.policy` (TorchScript, dict or flat observation, resume)."""

from __future__ import annotations

import importlib
import math
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parent.parent
TINY_ENV = "magwarp/TrajectoryPlanning-v0"
# one mover reaching goals on 3 x 3 tiles
TINY_KWARGS = '{"layout": [[1, 1, 1], [1, 1, 1], [1, 1, 1]], "num_movers": 1}'


def _example(name: str):
    """The training module behind ``examples/<name>.py`` (the example scripts only call it)."""
    modules = {"train_ppo": "magwarp.training.ppo", "train_sac_her": "magwarp.training.sac_her"}
    return importlib.import_module(modules[name])


def _success_rate(policy, seed: int = 123, num_envs: int = 64, steps: int = 150) -> float:
    """Goals reached / (reached + lost) of a deterministic policy on a fresh tiny env."""
    from magwarp.training import SuccessTracker, make_env, parse_env_kwargs

    env, _ = make_env(TINY_ENV, num_envs, "cpu", seed, parse_env_kwargs(TINY_KWARGS))
    tracker = SuccessTracker(num_envs, "cpu")
    obs, _ = env.reset(seed=seed)
    with torch.no_grad():
        for _ in range(steps):
            obs, reward, terminated, truncated, info = env.step(policy(obs))
            tracker.update(reward, terminated, truncated, info)
    return tracker.pop()["success_rate"]


def test_success_counts_goals_lost_by_collisions_and_timeouts_not_by_the_episode_length_cut():
    from magwarp.training import SuccessTracker

    tracker = SuccessTracker(3, "cpu")
    no = torch.zeros(3, dtype=torch.bool)
    reached = torch.tensor([[True, False], [False, False], [True, True]])
    # step 1: three goals reached; step 2: world 0 collides, world 1 times out, world 2 is cut by max_episode_steps
    tracker.update(torch.zeros(3), no, no, {"goals_reached": reached, "time_limit": no})
    ends = {"goals_reached": torch.zeros(3, 2, dtype=torch.bool), "time_limit": torch.tensor([False, False, True]),
            "mover_collision": torch.tensor([True, False, False])}
    tracker.update(torch.zeros(3), torch.tensor([True, False, False]), torch.tensor([False, True, True]), ends)
    out = tracker.pop()
    assert out["success_rate"] == 3 / (3 + 2 * 2) and out["episodes"] == 3 and out["collisions_per_episode"] == 1 / 3
    assert out["goals_per_1k_steps"] == 1000.0 * 3 / (2 * 3)  # 3 goals in 2 steps of 3 envs
    assert math.isnan(SuccessTracker(2, "cpu").pop()["goals_per_1k_steps"])  # no step counted yet


def _ppo_args(out, *extra):
    return _example("train_ppo").parse_args([
        "--env-id", TINY_ENV, "--env-kwargs", TINY_KWARGS, "--device", "cpu", "--seed", "1", "--num-envs", "64",
        "--num-steps", "16", "--hidden", "64,64", "--out", str(out), "--no-progress", "--deterministic",
        "--log-every", "1000", *extra,
    ])


def test_ppo_learns_tiny_reaching_task(tmp_path):
    ppo = _example("train_ppo")
    summary = ppo.train(_ppo_args(tmp_path, "--total-steps", "24576"))
    assert summary["global_step"] == 24576
    for name in ("policy.pt", "checkpoint.pt", "progress.csv", "curve.png"):
        assert (tmp_path / name).is_file(), name

    from magwarp.training import load_policy

    trained = load_policy(str(tmp_path), "cpu")
    # The untrained policy: the same network with its initial weights (mean action ~ 0: the mover hardly moves).
    torch.manual_seed(1)
    agent = ppo.Agent(6, 2, [64, 64], -0.5)
    untrained = lambda obs: agent.actor_mean(  # noqa: E731 - same normalisation-free scale as an initial policy
        torch.cat([obs[k] for k in ("achieved_goal", "desired_goal", "observation")], -1)).clamp(-1, 1) * 10.0
    before, after = _success_rate(untrained), _success_rate(trained)
    print(f"success untrained {before:.3f} trained {after:.3f}")
    assert after >= 0.9, f"trained success {after:.3f} (untrained {before:.3f})"
    assert after >= before + 0.4, f"trained success {after:.3f} is not well above the untrained {before:.3f}"


def test_policy_file_contract_and_resume(tmp_path):
    ppo = _example("train_ppo")
    ppo.train(_ppo_args(tmp_path, "--total-steps", "2048"))
    policy = torch.jit.load(str(tmp_path / "policy.pt"), map_location="cpu")
    assert policy.obs_dim == 6 and policy.action_dim == 2 and policy.env_id == TINY_ENV
    obs = {"observation": torch.randn(5, 2), "achieved_goal": torch.rand(5, 2) * 0.48,
           "desired_goal": torch.rand(5, 2) * 0.48}
    flat = torch.cat([obs["achieved_goal"], obs["desired_goal"], obs["observation"]], -1)
    a_dict, a_flat, a_sub = policy(obs), policy(flat), policy.flat(flat)
    assert a_dict.shape == (5, 2) and a_dict.dtype == torch.float32
    assert torch.equal(a_dict, a_flat) and torch.equal(a_flat, a_sub)
    assert float(a_dict.abs().max()) <= 10.0 + 1e-5  # within the action space (a_max = 10 m/s^2)

    # magwarp eval's loader (flattens the dict in sorted key order) gives the same actions as the dict call
    from magwarp.evaluate import load_policy as eval_load_policy
    from magwarp.training import make_env, parse_env_kwargs

    env, base = make_env(TINY_ENV, 5, "cpu", 0, parse_env_kwargs(TINY_KWARGS))
    env_obs, _ = env.reset(seed=0)
    assert torch.equal(eval_load_policy(str(tmp_path / "policy.pt"), base)(env_obs), policy(env_obs))

    from magwarp.training.policy import policy_metadata

    meta = policy_metadata(str(tmp_path / "policy.pt"))
    assert meta["env_id"] == TINY_ENV and meta["algo"] == "ppo"
    assert meta["obs_keys"] == ["achieved_goal", "desired_goal", "observation"]

    # Resume a copy of the run folder: the step counter continues, and the copy's CSV keeps its earlier rows and
    # grows (the folder the run was first written to is left alone).
    import shutil

    copy = shutil.copytree(tmp_path, tmp_path.parent / f"{tmp_path.name}_copy")
    csv_before = (tmp_path / "progress.csv").read_text()
    summary = ppo.train(ppo.parse_args(["--resume", str(copy), "--total-steps", "4096", "--no-progress"]))
    assert summary["global_step"] == 4096
    assert (copy / "progress.csv").read_text().count("\n") > csv_before.count("\n")
    assert (tmp_path / "progress.csv").read_text() == csv_before


def test_init_policy_warm_starts_the_actor_and_normaliser(tmp_path):
    """--init-policy: the agent's deterministic action is the policy file's (actor and normaliser loaded), a run
    starts from it, and a file that does not fit the run is refused naming the difference."""
    ppo = _example("train_ppo")
    ppo.train(_ppo_args(tmp_path / "a", "--total-steps", "2048"))
    path = str(tmp_path / "a" / "policy.pt")
    policy = torch.jit.load(path, map_location="cpu")
    scale = torch.full((2,), 10.0)
    from magwarp.training.common import RunningMeanStd

    agent, obs_rms = ppo.Agent(6, 2, [64, 64], -0.5), RunningMeanStd(6, "cpu")
    ppo.init_from_policy(path, agent, obs_rms, scale, "clip")
    x = torch.randn(32, 6) * torch.tensor([0.2, 0.2, 0.2, 0.2, 1.0, 1.0])
    with torch.no_grad():
        ours = agent.to_action(agent.actor_mean(obs_rms.normalize(x))) * scale
        torch.testing.assert_close(ours, policy(x), rtol=1e-5, atol=1e-5)
    assert float(obs_rms.count) == ppo.INIT_POLICY_COUNT
    for bad, match in (((ppo.Agent(6, 2, [32, 32], -0.5), "clip"), "--hidden"),
                       ((ppo.Agent(6, 2, [64, 64], -0.5, activation="relu"), "clip"), "--activation"),
                       ((ppo.Agent(6, 2, [64, 64], -0.5, squash="tanh"), "tanh"), "--squash")):
        with pytest.raises(ValueError, match=match):
            ppo.init_from_policy(path, bad[0], RunningMeanStd(6, "cpu"), scale, bad[1])
    with pytest.raises(ValueError, match="action scale"):
        ppo.init_from_policy(path, ppo.Agent(6, 2, [64, 64], -0.5), RunningMeanStd(6, "cpu"), scale * 2, "clip")
    # with --critic-warmup, the first iterations train the critic only: the actor (and its std) stays the file's
    summary = ppo.train(_ppo_args(tmp_path / "b", "--total-steps", "2048", "--init-policy", path,
                                  "--critic-warmup", "5"))
    assert summary["global_step"] >= 2048
    ckpt = torch.load(str(tmp_path / "b" / "checkpoint.pt"), map_location="cpu", weights_only=False)
    for k, v in policy.flat.net.state_dict().items():  # (the normaliser keeps learning the env's statistics)
        assert torch.equal(ckpt["agent"][f"actor_mean.{k}"], v), k
    assert torch.equal(ckpt["agent"]["log_std"], torch.full((2,), -0.5))
    fresh = ppo.Agent(6, 2, [64, 64], -0.5)
    critic = {k: v for k, v in ckpt["agent"].items() if k.startswith("critic")}
    assert all(critic[k].shape == v.shape for k, v in fresh.state_dict().items() if k.startswith("critic"))
    assert ckpt["lr"] == 3e-4  # the adaptive learning rate waited
    # when the actor starts, its Adam state starts from zero (steps counted from then; the critic's from the start)
    ppo.train(_ppo_args(tmp_path / "d", "--total-steps", "3072", "--init-policy", path, "--critic-warmup", "1"))
    ckpt = torch.load(str(tmp_path / "d" / "checkpoint.pt"), map_location="cpu", weights_only=False)
    names = [k for k, _ in ppo.Agent(6, 2, [64, 64], -0.5).named_parameters()]
    steps = {n: float(ckpt["optimizer"]["state"][i]["step"]) for i, n in enumerate(names)}
    per_iteration = steps["critic.0.weight"] / 3
    assert per_iteration >= 1 and steps["actor_mean.0.weight"] == steps["log_std"] == 2 * per_iteration
    ppo.train(_ppo_args(tmp_path / "c", "--total-steps", "2048", "--init-policy", path))
    ckpt = torch.load(str(tmp_path / "c" / "checkpoint.pt"), map_location="cpu", weights_only=False)
    assert not torch.equal(ckpt["agent"]["actor_mean.0.weight"], policy.flat.net.state_dict()["0.weight"])


def test_budget_is_required(tmp_path):
    ppo = _example("train_ppo")
    args = ppo.parse_args(["--env-id", TINY_ENV, "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="budget"):
        ppo.resolve_args(args)


def test_ppo_is_deterministic(tmp_path):
    ppo = _example("train_ppo")
    ppo.train(_ppo_args(tmp_path / "a", "--total-steps", "2048"))
    ppo.train(_ppo_args(tmp_path / "b", "--total-steps", "2048"))
    a = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=False)["agent"]
    b = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=False)["agent"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_her_buffer_future_goals_stay_in_their_episode():
    """Relabelled goals come from the same env and episode, at or after the sampled step (ring wrap-around too)."""
    sac = _example("train_sac_her")
    T, N, steps = 16, 3, 40
    dims = {k: 2 for k in ("observation", "achieved_goal", "desired_goal")}
    dims.update({"next_" + k: 2 for k in list(dims)}, action=1)
    buf = sac.HerReplayBuffer(T, N, dims, ["mover_collision"], "cpu")
    gen = torch.Generator().manual_seed(0)
    episode = torch.zeros(N, dtype=torch.int64)
    for g in range(steps):
        done = torch.rand(N, generator=gen) < 0.2
        # achieved goal after step g encodes (episode, step): episode ids differ per env, so are the envs' goals
        ag = torch.stack([(episode * 10 + torch.arange(N)).float(), torch.full((N,), float(g))], -1)
        obs = {"observation": torch.zeros(N, 2), "achieved_goal": ag, "desired_goal": torch.zeros(N, 2)}
        nxt = {"observation": torch.zeros(N, 2), "achieved_goal": ag, "desired_goal": torch.zeros(N, 2)}
        buf.add(obs, torch.zeros(N, 1), torch.zeros(N), nxt, torch.zeros(N, dtype=torch.bool), done,
                {"mover_collision": torch.zeros(N, dtype=torch.bool)})
        episode += done.long()
    calls = []

    def compute_reward(achieved, desired, info):
        calls.append(info)
        return (achieved == desired).all(-1).float()

    out = buf.sample(4096, 1.0, compute_reward)
    goal, ach = out["desired_goal"], out["next_achieved_goal"]
    assert torch.equal(goal[:, 0], ach[:, 0]), "relabelled goal from another env or episode"
    assert bool((goal[:, 1] >= ach[:, 1]).all()), "relabelled goal from an earlier step"
    assert bool((goal[:, 1] >= steps - T).all()) and bool((goal[:, 1] <= steps - 1).all())
    assert bool((goal[:, 1] > ach[:, 1]).any()), "future strategy never looked ahead"
    assert set(calls[0]) == {"mover_collision"}
    assert torch.equal(out["reward"], (ach == goal).all(-1).float())


def test_sac_her_runs_resumes_and_saves(tmp_path):
    sac = _example("train_sac_her")
    common = ["--env-id", TINY_ENV, "--env-kwargs", TINY_KWARGS, "--device", "cpu", "--seed", "0", "--num-envs", "16",
              "--batch-size", "128", "--hidden", "32,32", "--learning-starts", "4", "--buffer-steps", "64",
              "--no-progress", "--log-every", "1000"]
    summary = sac.train(sac.parse_args([*common, "--out", str(tmp_path), "--total-steps", "320"]))
    assert summary["global_step"] == 320
    for name in ("policy.pt", "checkpoint.pt", "progress.csv", "curve.png"):
        assert (tmp_path / name).is_file(), name
    first = tmp_path.parent / f"{tmp_path.name}_first"  # the run is moved: it continues where its checkpoint is now
    tmp_path.rename(first)
    summary = sac.train(sac.parse_args(["--resume", str(first), "--total-steps", "480", "--no-progress"]))
    assert summary["global_step"] == 480 and not tmp_path.exists()
    tmp_path = first
    policy = torch.jit.load(str(tmp_path / "policy.pt"), map_location="cpu")
    obs = {"observation": torch.zeros(4, 2), "achieved_goal": torch.rand(4, 2), "desired_goal": torch.rand(4, 2)}
    a = policy(obs)
    assert a.shape == (4, 2) and float(a.abs().max()) <= 10.0
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    assert ckpt["algo"] == "sac-her" and ckpt["updates"] > 0


def _learner(sac, device: str, *extra: str):
    args = sac.resolve_args(sac.parse_args(["--env-id", TINY_ENV, "--device", device, "--total-steps", "1",
                                            "--hidden", "32,32", *extra]))
    return sac.SacLearner(6, 2, args, torch.device(device))


def _sample(n: int, device: str, seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    out = {}
    for k in ("achieved_goal", "desired_goal", "observation"):
        out[k], out["next_" + k] = torch.randn(n, 2, generator=g), torch.randn(n, 2, generator=g)
    out["action"] = torch.rand(n, 2, generator=g) * 2 - 1
    out["reward"] = -torch.rand(n, generator=g)
    out["terminated"] = torch.rand(n, generator=g) < 0.1
    return {k: v.to(device) for k, v in out.items()}


def test_sac_learner_runs_one_update_per_minibatch_and_follows_its_lr():
    sac = _example("train_sac_her")
    torch.manual_seed(0)
    learner = _learner(sac, "cpu", "--policy-delay", "2", "--lr", "1e-3")
    actor0 = [p.detach().clone() for p in learner.actor.parameters()]
    losses = learner.learn(_sample(8 * 16, "cpu", 0), 8)
    assert set(losses) == {"loss_q", "loss_pi"} and all(torch.isfinite(v) for v in losses.values())
    steps = {name: float(next(iter(opt.state.values()))["step"]) for name, opt in
             (("critic", learner.critic_opt), ("actor", learner.actor_opt), ("alpha", learner.alpha_opt))}
    assert steps == {"critic": 8.0, "actor": 4.0, "alpha": 4.0}  # policy_delay 2: an actor update per 2 critic ones
    assert any(not torch.equal(a, b) for a, b in zip(actor0, learner.actor.parameters()))
    learner.set_lr(0.0)  # a finished linear schedule: the actor stays put, the target critic still tracks
    actor1 = [p.detach().clone() for p in learner.actor.parameters()]
    target1 = [p.detach().clone() for p in learner.critic_target.parameters()]
    learner.learn(_sample(8 * 16, "cpu", 1), 8)
    assert all(torch.equal(a, b) for a, b in zip(actor1, learner.actor.parameters()))
    assert any(not torch.equal(a, b) for a, b in zip(target1, learner.critic_target.parameters()))
    with pytest.raises(ValueError, match="multiple of policy_delay"):
        learner.learn(_sample(7 * 16, "cpu", 2), 7)
    with pytest.raises(ValueError, match="multiple of --policy-delay"):
        _learner(sac, "cpu", "--policy-delay", "3", "--updates-per-step", "32")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a GPU")
def test_sac_graphed_updates_match_eager_ones():
    """The captured update graph, replayed, moves every weight as the eager updates do (its warm-up is undone)."""
    sac = _example("train_sac_her")
    weights = {}
    for mode in ("off", "on"):
        torch.manual_seed(0)
        learner = _learner(sac, "cuda", "--cuda-graph", mode, "--policy-delay", "2")
        assert learner.graphed == (mode == "on")
        torch.manual_seed(1)
        for seed in range(3):  # the first call captures, the later ones replay on freshly staged minibatches
            losses = learner.learn(_sample(8 * 64, "cuda", seed), 8)
        torch.cuda.synchronize()
        weights[mode] = [p.detach().cpu() for m in (learner.actor, learner.critic, learner.critic_target)
                         for p in m.parameters()] + [learner.log_alpha.detach().cpu()]
        assert all(torch.isfinite(v) for v in losses.values())
    for a, b in zip(weights["off"], weights["on"]):
        torch.testing.assert_close(b, a, atol=1e-4, rtol=1e-3)


def test_paper_runs_build_their_envs():
    """Every paper run's training and evaluation options are accepted by its env (names and values)."""
    import gymnasium as gym

    from magwarp.training.paper import PAPER_RUNS

    for name, run in PAPER_RUNS.items():
        for kwargs in (run.train_kwargs, run.eval_kwargs):
            env = gym.make_vec(run.env_id, num_envs=1, device="cpu", **kwargs).unwrapped
            if "num_cycles" in kwargs:
                assert env.num_cycles == kwargs["num_cycles"], name
            if "num_movers" in kwargs:
                assert env.num_movers == kwargs["num_movers"], name
            if "min_coverage" in kwargs:
                assert env.min_coverage == kwargs["min_coverage"]
            if "obstacle_mode" in kwargs:
                assert env.obstacle_mode == kwargs["obstacle_mode"]
            if "pd_max_acc" in kwargs:  # a residual's retuned base PD (lev_residual_soft)
                assert env.baseline.max_acc == tuple(kwargs["pd_max_acc"]), name
                assert env.baseline.kp == pytest.approx((2 * math.pi * kwargs["pd_frequency"]) ** 2), name
            env.close()


@pytest.mark.parametrize("algo", ["ppo", "sac-her"])
def test_train_command(tmp_path, algo, capsys):
    from magwarp.cli import main

    out = tmp_path / algo
    extra = "--num-steps 8 --hidden 16,16" if algo == "ppo" else "--hidden 16,16 --batch-size 64 --learning-starts 2"
    argv = ["train", TINY_ENV, "--algo", algo, "--device", "cpu", "--num-envs", "16", "--total-steps", "256",
            "--out", str(out), "--env-kwargs", TINY_KWARGS, "--args", extra]
    assert main(argv) == 0
    assert f"{algo} done" in capsys.readouterr().out
    assert (out / "policy.pt").is_file() and (out / "curve.png").is_file()
    # --resume picks the checkpoint's algorithm; a mismatching --algo is a usage error
    other = "sac-her" if algo == "ppo" else "ppo"
    assert main(["train", "--resume", str(out), "--algo", other, "--total-steps", "512"]) == 2
    assert "trained with" in capsys.readouterr().err
    assert main(["train", "magwarp/NoSuchEnv-v0", "--minutes", "1"]) == 2


def test_suite_runs_and_packs(tmp_path, capsys):
    from magwarp.training import suite

    work, out = tmp_path / "runs", tmp_path / "out"
    rc = suite.main(["--minutes", "0.01", "--runs", "b0_ppo", "--work", str(work), "--out", str(out), "--device", "cpu",
                     "--args", "--num-envs 8 --num-steps 4 --hidden 16,16 --eval-steps 2"])
    assert rc == 0, (work / "b0_ppo.log").read_text()[-2000:]
    import tarfile

    with tarfile.open(out / "b0_ppo.tgz") as tar:
        names = set(tar.getnames())
    assert {"b0_ppo/policy.pt", "b0_ppo/checkpoint.pt", "b0_ppo/progress.csv", "b0_ppo.log"} <= names
    assert "| b0_ppo | magwarp/TrajectoryPlanningB0-v0 |" in capsys.readouterr().out


def test_suite_passes_a_runs_own_script_options(tmp_path, monkeypatch):
    """A run's script_args (its seed) reach its training command, before the suite-wide --args (which win)."""
    from magwarp.training import suite
    from magwarp.training.paper import PAPER_RUNS

    commands = []

    class Done:
        def __init__(self, cmd, **kwargs):
            commands.append(cmd)

        def wait(self):
            return 0

    monkeypatch.setattr(suite.subprocess, "Popen", Done)
    runs = ["b0_ppo_starts40", "b0_ppo_starts40_seed1", "b0_ppo_starts40_seed2"]
    assert suite.main(["--minutes", "1", "--runs", ",".join(runs), "--work", str(tmp_path), "--device", "cpu",
                       "--args", "--num-envs 8"]) == 0
    seeds = [cmd[cmd.index("--seed") + 1] if "--seed" in cmd else None for cmd in commands]
    assert seeds == [None, "1", "2"] and all(cmd[-2:] == ["--num-envs", "8"] for cmd in commands)
    assert PAPER_RUNS["b0_ppo_starts40_seed1"].train_kwargs == PAPER_RUNS["b0_ppo_starts40"].train_kwargs


def test_time_to_target_first_crossing_stops_and_is_written(tmp_path, capsys):
    """A periodic deterministic evaluation finds the first crossing of --target; --stop-at-target ends the run there;
    the time to target is printed and written to run.json (every evaluation too) and the policy's metadata."""
    import json

    ppo = _example("train_ppo")
    args = _ppo_args(tmp_path, "--total-steps", "24576", "--target", "0.6", "--eval-every", "1e-9", "--eval-envs", "16",
                     "--target-eval-steps", "150", "--stop-at-target", "--eval-steps", "0")
    summary = ppo.train(args)
    run = json.loads((tmp_path / "run.json").read_text())
    evals = run["evals"]
    assert run["summary"] == json.loads(json.dumps(summary)) and summary["target"] == 0.6
    # one evaluation per iteration (16 x 64 steps); the last is the first to reach the target, and training stopped
    assert len(evals) == summary["global_step"] // 1024 and summary["global_step"] < 24576
    assert evals[-1]["success_rate"] >= 0.6 and all(e["success_rate"] < 0.6 for e in evals[:-1])
    assert summary["time_to_target_step"] == evals[-1]["global_step"] == summary["global_step"]
    assert summary["time_to_target_s"] == evals[-1]["process_s"] > summary["time_to_target_train_s"] > 0
    assert all(e["episodes"] > 0 for e in evals)
    out = capsys.readouterr().out
    assert "time to target: success" in out and f"time to target (0.6): {summary['time_to_target_s']:.1f} s" in out
    from magwarp.training.policy import policy_metadata

    assert policy_metadata(str(tmp_path / "policy.pt"))["time_to_target_s"] == summary["time_to_target_s"]
    # resuming a run that reached its target keeps the first crossing
    resumed = ppo.train(ppo.parse_args(["--resume", str(tmp_path), "--total-steps", str(summary["global_step"] + 1024),
                                        "--no-progress", "--stop-at-target"]))
    assert resumed["time_to_target_s"] == summary["time_to_target_s"]


def test_targets_default_to_the_papers_and_are_checked(tmp_path):
    from magwarp.training.loop import default_target

    assert [default_target(f"magwarp/{t}-v0") for t in ("TrajectoryPlanningB0", "PushBox", "PushT",
                                                          "PushWithObstacles", "TrajectoryPlanning")] == \
        [0.99, 0.99, 0.73, 0.91, None]
    ppo = _example("train_ppo")
    args = ppo.resolve_args(ppo.parse_args(["--env-id", "magwarp/PushBox-v0", "--minutes", "1"]))
    assert args.target == 0.99 and args.eval_every == 10.0
    args = ppo.resolve_args(ppo.parse_args(["--env-id", TINY_ENV, "--minutes", "1"]))
    assert args.target is None and args.eval_every == 0.0
    for bad in ("99", "0", "-0.5"):
        with pytest.raises(ValueError, match="--target is a success rate"):
            ppo.resolve_args(ppo.parse_args(["--env-id", TINY_ENV, "--minutes", "1", "--target", bad]))
