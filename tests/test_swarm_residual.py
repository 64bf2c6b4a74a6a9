"""magwarp/SwarmResidual-v0: a zero correction is the planner on the shielded swarm env bit for bit (through resets
and autoresets), the planner runs once per step, the observation is the base env's plus the planner's action, a
correction adds ``residual_scale * action`` before the shield, bad options are refused, and the env passes the
Gymnasium, TorchRL and PettingZoo checks in all its views; on CUDA the recorded step graph (the planner inside it)
replays the eager step bit for bit."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch

import magwarp  # noqa: F401 - registers the ids
from magwarp.swarm import FlatSwarmEnv, SwarmEnv, SwarmPlanner, SwarmResidualConfig, SwarmResidualEnv
from test_swarm_graph import CUDA, _run_twins  # tests/ is on sys.path

SMALL = dict(num_movers=12, layout=np.ones((6, 6)), device="cpu")
TINY = dict(num_movers=5, layout=np.ones((4, 4)), k=2, num_rays=4, num_cycles=10, device="cpu")


def _pair(seed: int, planner: dict | None = None, **options):
    """The residual env and the shielded plain env driven by the planner, on the same worlds."""
    opts = {**SMALL, **options}
    residual = SwarmResidualEnv(2, seed=seed, planner=planner, **opts)
    plain = SwarmEnv(2, seed=seed, shield=True, **opts)
    return residual, plain, SwarmPlanner(plain, **(planner or {}))


def test_zero_correction_is_the_planner_with_the_shield_bit_for_bit(rng, monkeypatch):
    seed = int(rng.integers(1 << 30))
    residual, plain, planner = _pair(seed)
    unshielded = SwarmEnv(2, seed=seed, **SMALL)
    bare = SwarmPlanner(unshielded)
    assert residual.config.shield and residual.shield_filter is not None
    zero = residual.scripted_policy()(None)
    assert torch.equal(zero, torch.zeros(2, 12, 2))
    obs_r, _ = residual.reset()
    obs_p, _ = plain.reset()
    unshielded.reset()
    calls = []
    call = SwarmPlanner.__call__
    monkeypatch.setattr(SwarmPlanner, "__call__", lambda self, obs=None: calls.append(self) or call(self, obs))
    shield_acted, goals = False, 0
    for t in range(40):
        action = planner()
        # the observation shows the action the planner is about to take
        torch.testing.assert_close(obs_r[..., -2:] * residual.config.a_max, action, rtol=1e-6, atol=1e-6)
        assert torch.equal(residual.planner_action, action), f"seed {seed}, step {t}"
        assert torch.equal(residual.planner.stuck, planner.stuck)
        obs_p, reward_p, _, _, info_p = plain.step(action)
        before = len(calls)
        obs_r, reward_r, _, _, info_r = residual.step(zero)
        assert calls[before:] == [residual.planner]  # once per step, at the observation
        _, _, _, _, info_u = unshielded.step(bare())
        assert torch.equal(residual.sim.pos, plain.sim.pos), f"seed {seed}, step {t}"
        assert torch.equal(residual.sim.vel, plain.sim.vel) and torch.equal(residual.goals, plain.goals)
        assert torch.equal(obs_r[..., :-2], obs_p) and torch.equal(reward_r, reward_p)
        for key in info_p:
            assert torch.equal(info_r[key], info_p[key]), key
        # the shield passes an action it keeps bit for bit: until it first changes one of the planner's, the run
        # is the planner's on the unshielded env too (after that the two may part: the shield is stricter)
        shield_acted |= bool(info_p["shield_active"].any())
        if not shield_acted:
            assert torch.equal(unshielded.sim.pos, plain.sim.pos), f"seed {seed}, step {t}"
        goals += int(info_r["goal_reached"].sum())
    assert goals > 0 and not info_r["collided"].any()  # the planner works here (the test compares real motion)


def test_resets_and_autoresets_restart_the_planner(rng):
    """World ends (a step limit), a full reset and a masked reset: the residual env's planner keeps the counters of
    a planner restarted with the worlds (patience 1: the counter decides the action at every episode start)."""
    seed = int(rng.integers(1 << 30))
    residual, plain, planner = _pair(seed, {"patience": 1}, max_episode_steps=7)
    calls = []
    call = SwarmPlanner.__call__

    def counted(self, obs=None):
        calls.append(id(self))
        return call(self, obs)

    zero = torch.zeros(2, 12, 2)
    ended = 0

    def lockstep(steps: int) -> None:
        nonlocal ended
        for t in range(steps):
            action = planner()  # the plain loop plans at the start of the step, the residual env at its last one
            assert torch.equal(residual.planner_action, action), f"seed {seed}, step {t}"
            assert torch.equal(residual.planner.stuck, planner.stuck), f"seed {seed}, step {t}"
            _, _, terminated, truncated, _ = plain.step(action)
            planner.reset(terminated | truncated)  # the plain loop's planner restarts with the worlds
            before = len(calls)
            _, _, _, truncated_r, _ = residual.step(zero)
            assert torch.equal(truncated_r, truncated) and torch.equal(residual.sim.pos, plain.sim.pos)
            # where worlds can end, every step plans a second time for the worlds that restart (kept only for them:
            # no host sync to skip it when none does); without ends once (test_zero_correction_...)
            assert calls[before:] == [id(residual.planner)] * 2, f"step {t}"
            ended += int(truncated.sum())

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(SwarmPlanner, "__call__", counted)
        lockstep(18)
        assert ended == 4  # both worlds ended twice (steps 7 and 14)
        # a full reset: one planner call, fresh counters
        before = len(calls)
        residual.reset(seed=seed + 1)
        assert calls[before:] == [id(residual.planner)]
        plain.reset(seed=seed + 1)
        planner.reset()
        lockstep(3)
        action = planner()
        assert torch.equal(residual.planner_action, action) and torch.equal(residual.planner.stuck, planner.stuck)
    # a masked reset (TorchRL's): the reset world restarts, the other keeps its action and counters
    mask = torch.tensor([True, False])
    kept_action, kept_stuck = residual.planner_action[1].clone(), residual.planner.stuck[1].clone()
    obs, _ = residual.reset(options={"reset_mask": mask})
    plain.reset(options={"reset_mask": mask})
    planner.reset(mask)
    fresh = planner()
    assert torch.equal(residual.planner_action[0], fresh[0])
    assert torch.equal(residual.planner.stuck[0], planner.stuck[0])
    assert torch.equal(residual.planner_action[1], kept_action) and torch.equal(residual.planner.stuck[1], kept_stuck)
    torch.testing.assert_close(obs[..., -2:] * residual.config.a_max, residual.planner_action, rtol=1e-6, atol=1e-6)


def test_a_respawned_mover_restarts_its_deadlock_counter(rng):
    """Without the shield a correction can collide; the collided movers respawn at rest and start with a fresh
    planner's counter (then counted once: 1)."""
    seed = int(rng.integers(1 << 30))
    env = SwarmResidualEnv(2, seed=seed, shield=False, residual_scale=2.0, **SMALL)
    respawned = 0
    for _ in range(30):
        env.planner.stuck.fill_(3)  # 3 before the step: 4 (still) or 0 (moving) after it, but 0 or 1 after a respawn
        pos = env.sim.pos[..., :2]
        to = pos.mean(dim=1, keepdim=True) - pos  # everyone towards the middle: collisions
        env.step(10.0 * to / to.norm(dim=-1, keepdim=True).clamp_min(1e-6))
        want = env._want_respawn  # the step's respawns (collided, or still waiting for a spot)
        stuck = env.planner.stuck
        assert (stuck[want] <= 1).all() and ((stuck[~want] == 4) | (stuck[~want] == 0)).all(), f"seed {seed}"
        respawned += int((stuck[want] == 1).sum())
    assert respawned > 0, f"seed {seed}: the test needs collisions"


def test_observation_is_the_base_one_plus_the_planners_action():
    env = SwarmResidualEnv(3, seed=1, a_max=8.0, **SMALL)
    plain = SwarmEnv(3, seed=1, shield=True, a_max=8.0, **SMALL)
    width = plain.single_observation_space.shape[1]
    assert env.single_observation_space.shape == (12, width + 2) and env.observation_space.shape == (3, 12, width + 2)
    assert env.single_action_space == plain.single_action_space
    obs, _ = env.reset(seed=2)
    ref, _ = plain.reset(seed=2)
    assert obs.shape == (3, 12, width + 2) and env.observation_space.contains(obs.numpy())
    assert torch.equal(obs[..., :width], ref)
    assert torch.equal(obs[..., width:], env.planner_action / 8.0)
    assert float(env.planner_action.norm(dim=-1).max()) > 1.0  # the movers start at rest: the planner accelerates
    flat = env.agent_view()
    assert isinstance(flat, FlatSwarmEnv) and flat.single_observation_space.shape == (width + 2,)
    fobs, _ = flat.reset(seed=2)
    assert torch.equal(fobs, obs.reshape(36, -1))


def _record_shield(monkeypatch) -> list:
    """Every action the env's shield is given, from now on."""
    seen = []
    shield = SwarmEnv._shield

    def record(self, action):
        seen.append(action.clone())
        return shield(self, action)

    monkeypatch.setattr(SwarmEnv, "_shield", record)
    return seen


def test_a_correction_adds_its_scaled_action_before_the_shield(rng, monkeypatch):
    seen = _record_shield(monkeypatch)
    env = SwarmResidualEnv(2, seed=4, residual_scale=0.3, **SMALL)
    for _ in range(3):
        env.step(torch.zeros(2, 12, 2))
    base = env.planner_action.clone()
    a = torch.as_tensor(rng.uniform(-10.0, 10.0, (2, 12, 2)), dtype=torch.float32)  # the action space's range
    _, _, _, _, info = env.step(a)
    torch.testing.assert_close(seen[-1] - base, 0.3 * a, rtol=0, atol=1e-5)
    assert not info["collided"].any()


def test_the_gate_corrects_only_fast_movers_out_of_their_escape(rng, monkeypatch):
    """``gate_speed``: the shield sees the planner's action alone for movers slower than the gate or in the planner's
    deadlock escape, and the planner's action plus the scaled correction for the others."""
    seen = _record_shield(monkeypatch)
    env = SwarmResidualEnv(2, seed=6, residual_scale=0.5, gate_speed=0.3, **SMALL)
    for _ in range(4):
        env.step(torch.zeros(2, 12, 2))
    env.planner.stuck[0, :3] = env.planner.patience  # three movers in their escape
    speed = env.sim.vel[..., :2].norm(dim=-1)
    fast = (speed >= 0.3) & (env.planner.stuck < env.planner.patience)
    assert fast.any() and (~fast).any(), f"{rng}: {speed}"
    base = env.planner_action.clone()
    a = torch.as_tensor(rng.uniform(-10.0, 10.0, (2, 12, 2)), dtype=torch.float32)
    env.step(a)
    torch.testing.assert_close(seen[-1] - base, 0.5 * a * fast[..., None], rtol=0, atol=1e-5)
    for bad in (-0.1, float("inf"), float("nan"), True, "0.3"):
        with pytest.raises(ValueError, match=f"gate_speed must be a finite speed >= 0 \\(m/s\\), got {bad!r}"):
            SwarmResidualConfig(gate_speed=bad)


@pytest.mark.parametrize("bad", [0.0, -0.5, 2.5, float("nan"), True, "0.5"])
def test_bad_residual_scales_are_refused(bad):
    with pytest.raises(ValueError, match="residual_scale"):
        SwarmResidualEnv(1, residual_scale=bad, **TINY)


def test_bad_options_are_refused():
    with pytest.raises(TypeError, match=r"unknown planner options \['bogus'\]"):
        SwarmResidualEnv(1, planner={"bogus": 1.0, "traffic": "lanes"}, **TINY)
    with pytest.raises(TypeError, match="planner must be a dict"):
        SwarmResidualEnv(1, planner=["traffic"], **TINY)
    with pytest.raises(ValueError, match="traffic must be one of"):
        SwarmResidualEnv(1, planner={"traffic": "roundabout"}, **TINY)
    with pytest.raises(ValueError, match="learn_jerk"):
        SwarmResidualEnv(1, learn_jerk=True, shield=False, **TINY)
    with pytest.raises(TypeError, match="unknown SwarmResidualEnv options"):
        SwarmResidualEnv(1, residual=0.5, **TINY)
    with pytest.raises(TypeError, match="must be a SwarmResidualConfig"):
        SwarmResidualEnv(1, config=magwarp.swarm.SwarmConfig(), device="cpu")
    with pytest.raises(ValueError, match="mask must be a bool tensor"):
        SwarmResidualEnv(1, **TINY).planner.reset(torch.zeros(3, dtype=torch.bool))
    cfg = SwarmResidualConfig(num_movers=5, layout=np.ones((4, 4)), residual_scale=0.25, planner={"traffic": "free"})
    env = SwarmResidualEnv(1, config=cfg, device="cpu")
    assert env.residual_scale == 0.25 and env.planner.traffic == "free" and env.config.planner == {"traffic": "free"}


def test_registered_and_the_checkers_pass_in_every_view():
    from gymnasium.utils.env_checker import check_env

    env = gym.make("magwarp/SwarmResidual-v0", **TINY)
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=1)
    assert obs.shape == (5, 4 + 5 * 2 + 4 + 2) and obs.dtype == np.float32
    vec = gym.make_vec("magwarp/SwarmResidual-v0", num_envs=2, residual_scale=0.2, **TINY)
    assert type(vec.unwrapped) is SwarmResidualEnv and vec.unwrapped.residual_scale == 0.2
    pytest.importorskip("torchrl")
    from torchrl.envs.utils import check_env_specs

    from magwarp.swarm import SwarmParallelEnv, SwarmTorchRLEnv

    trl = SwarmTorchRLEnv(SwarmResidualEnv(2, max_episode_steps=3, **TINY))
    check_env_specs(trl, seed=0)
    td = trl.rollout(5, break_when_any_done=False)
    assert td["agents", "observation"].shape == (2, 5, 5, 20)
    pytest.importorskip("pettingzoo")
    from pettingzoo.test import parallel_api_test

    pz = SwarmParallelEnv(SwarmResidualEnv(1, max_episode_steps=6, autoreset=False, **TINY))
    parallel_api_test(pz, num_cycles=20)
    obs, _ = pz.reset(seed=1)
    assert obs["mover_0"].shape == (20,)


def test_ppo_preset_and_paper_run_start_at_the_planner():
    from magwarp.training import ppo
    from magwarp.training.paper import PAPER_RUNS

    run = PAPER_RUNS["swarm_residual"]
    assert run.env_id == "magwarp/SwarmResidual-v0" and run.algo == "ppo"
    args = ppo.resolve_args(ppo.parse_args(["--env-id", run.env_id, "--device", "cpu", "--minutes", "1"]))
    assert args.actor_init == "zero"  # its preset, not "Swarm"'s: the mean correction is 0 until the first update
    train, evaluate = json.loads(run.train_json()), json.loads(run.eval_json())
    assert train["planner"] == {"traffic": "lanes"} and "planner" not in evaluate  # see paper.py
    SwarmResidualConfig(**{**train, "num_movers": 16})  # valid options


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
@pytest.mark.parametrize("ends", [False, True])
def test_graph_step_matches_eager(rng, ends):
    """The planner runs inside the env's recorded CUDA graph (its counters and action updated in place): random
    corrections, the graph replay against the same launches eagerly, through autoresets (a step limit) and a
    reseeded reset; with the shield off, through respawns too."""
    options = dict(max_episode_steps=4, planner={"patience": 2}) if ends else dict(shield=False, residual_scale=2.0)
    counts = _run_twins(rng, 12, 8, reseed_at=8, cls=SwarmResidualEnv, extra=("planner_action", "planner.stuck"),
                        num_movers=24, occupancy=0.5, **options)
    assert counts["done" if ends else "respawns"] > 0, f"{rng}"


def _zero_policy(path: str, env_id: str, train: dict, evaluate: dict | None = None) -> str:
    """A policy file whose action is zero (a residual policy at its start), with its env options stored."""
    from magwarp.training.common import RunningMeanStd
    from magwarp.training.policy import save_policy

    n_obs = 4 + 5 * 8 + 8 + 2  # the default local view, and the planner's action
    net = torch.nn.Linear(n_obs, 2)
    torch.nn.init.zeros_(net.weight)
    torch.nn.init.zeros_(net.bias)
    save_policy(path, net, RunningMeanStd(n_obs, "cpu"), torch.full((2,), 10.0), squash="clip", env_id=env_id,
                metadata={"env_kwargs": json.dumps(train), "eval_env_kwargs": evaluate and json.dumps(evaluate)})
    return path


def test_scaling_study_runs_a_residual_policy_on_its_env(tmp_path):
    """examples/swarm_scaling.py --policy: the policy's env (id and evaluation options, the study's size, layout and
    seed); a zero correction on the same worlds as the planner row reaches the same goals."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "swarm_scaling", Path(__file__).resolve().parent.parent / "examples" / "swarm_scaling.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    path = _zero_policy(str(tmp_path / "policy.pt"), "magwarp/SwarmResidual-v0",
                        {"num_movers": 64, "planner": {"traffic": "lanes"}, "reward_progress": 5.0},
                        {"num_movers": 64, "residual_scale": 0.4})
    env_id, options = study.policy_env_options(path, "auto")
    assert env_id == "magwarp/SwarmResidual-v0" and options == {"residual_scale": 0.4, "planner": {"traffic": "auto"}}
    rows = study.study([12], 0.25, 1.2, "cpu", policy=path)
    assert [r["controller"] for r in rows] == ["planner", "residual"]
    assert rows[1]["goals"] == rows[0]["goals"] > 0 and rows[1]["collisions"] == 0
    # a policy that names no env options acts on the plain swarm env
    plain = _zero_policy(str(tmp_path / "plain.pt"), "magwarp/Swarm-v0", {})
    assert study.policy_env_options(plain, "lanes") == ("magwarp/Swarm-v0", {})
    with pytest.raises(SystemExit, match="not a swarm env"):
        study.policy_env_options(_zero_policy(str(tmp_path / "b0.pt"), "magwarp/TrajectoryPlanningB0-v0", {}), "auto")
