"""The levitation baseline and benchmark: the PD law holds movers at any yaw (its tilt error is turned into the world
frame), and benchmarks/levitation_policy.py compares a policy file with it on the same worlds (a tiny CPU run)."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path

import pytest
import torch

from magnetics_helpers import coarse_model, magnetics_cache  # noqa: F401  (tests/ is on sys.path; a fixture)

from magwarp.envs.levitation import LevitationEnv
from magwarp.policies.levitation import LevitationPD

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import levitation_policy as bench  # noqa: E402

MAG = coarse_model()


def test_pd_baseline_holds_movers_at_every_yaw():
    # 16 worlds of random yaw: before the fix, those with |yaw| > ~pi/2 tipped over (roll and pitch were corrected
    # about the world's axes, so about the wrong ones once the mover had turned)
    env = LevitationEnv(16, magnetics=MAG, device="cpu", seed=0, autoreset=False)
    policy = LevitationPD(env)
    obs, _ = env.reset(seed=0)
    assert (obs[:, 5].abs() > 2.0).sum() >= 3  # several movers face the other way
    failed = torch.zeros(16, dtype=torch.bool)
    for _ in range(150):
        obs, _, terminated, _, _ = env.step(policy(obs))
        failed |= terminated
    pos_err, rot_err = env.errors()
    # held, not tipped (the law clips its feedback accelerations, so the last worlds are still settling: 0.18 mm)
    assert not failed.any() and pos_err.max() < 5e-4 and rot_err.max() < 5e-3, (failed, pos_err, rot_err)


@pytest.fixture
def coarse_default(monkeypatch):
    """``LevitationEnv()`` builds the coarse model of these tests by default (the benchmark makes envs by id)."""
    from magwarp.magnetics import drive

    coarse = dataclasses.make_dataclass("CoarseModel", [("table", object, dataclasses.field(default=MAG.table))],
                                        bases=(drive.MagneticModel,), frozen=True)
    monkeypatch.setattr(drive, "MagneticModel", coarse)


def _zero_policy(path: Path, env_id: str = "magwarp/LevitationWrench-v0",
                 env_kwargs: str = '{"max_episode_steps": 40}') -> None:
    """A policy file as magwarp train writes it for ``env_id`` (a wrench action), whose action is always zero."""
    from magwarp.training.common import RunningMeanStd
    from magwarp.training.policy import mlp, save_policy

    net = mlp(19, [8], 6)
    for p in net.parameters():
        torch.nn.init.zeros_(p)
    save_policy(str(path), net, RunningMeanStd(19, "cpu"), torch.ones(6), squash="clip",
                env_id=env_id, metadata={"algo": "ppo", "env_kwargs": env_kwargs})


def test_benchmark_compares_a_policy_with_the_baseline(coarse_default, tmp_path, capsys):
    _zero_policy(tmp_path / "policy.pt")
    out = tmp_path / "lev.json"
    assert bench.main(["--policy", str(tmp_path), "--envs", "3", "--pd-frequencies", "10", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    rows = json.loads(out.read_text())
    assert [(r["controller"], r["action"], r["frequency_hz"]) for r in rows] == [
        ("PD 10 Hz", "wrench", 10.0), ("PD 15 Hz", "wrench", 15.0), ("PD 15 Hz", "currents", 15.0),
        (f"policy {tmp_path.name}", "wrench", None)]
    *pds, zero = rows
    for r in rows:  # the policy's env: its id and options, one 40-step episode
        assert r["steps"] == 40 and r["worlds"] == 3 and r["env_id"] == "magwarp/LevitationWrench-v0"
        assert r["date_utc"] and r["versions"]["torch"] and r["command"].startswith("python")
    # zero wrench: every mover falls within a few ms, so no world is flown by everyone: nothing to compare
    assert zero["failed"] == 1.0 and zero["success"] == 0.0 and zero["compared"] == 0
    for r in pds:  # the PD hovers without failing
        assert r["failed"] == 0 and r["compared"] == 0 and math.isnan(r["energy_j"])
    assert "VERDICT: policy beats baseline on energy at equal (or better) tracking error: NO" in text
    assert all(r["verdict"] is False for r in rows)


def test_benchmark_measures_a_retuned_residual_base_against_the_shipped_pd(coarse_default, tmp_path, capsys):
    # a residual over a retuned PD (lev_residual_soft): the PD rows stay the shipped PD's (15 Hz, max_acc 5/60), the
    # base alone gets its own row, and a zero residual is exactly that base
    _zero_policy(tmp_path / "policy.pt", "magwarp/LevitationResidual-v0",
                 '{"max_episode_steps": 30, "pd_frequency": 8.0, "pd_max_acc": [8.0, 100.0]}')
    out = tmp_path / "lev.json"
    assert bench.main(["--policy", str(tmp_path), "--envs", "3", "--pd-frequencies", "8", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    rows = json.loads(out.read_text())
    assert [r["controller"] for r in rows] == ["PD 8 Hz", "PD 15 Hz", "PD 8 Hz, max_acc 8/100 (policy's base)",
                                               "PD 15 Hz", f"policy {tmp_path.name}"]
    soft, shipped, base, _, zero = rows
    assert all(r["failed"] == 0 and r["compared"] == 3 for r in rows)
    for key in ("energy_j", "pos_rms_mm", "rot_rms_mrad"):
        assert zero[key] == pytest.approx(base[key], rel=1e-6)  # the zero residual is its base
    # the 8 Hz sweep row is the shipped limits' 8 Hz PD, not the base: the setpoint moves hit 5 m/s^2, not 8
    assert soft["pos_rms_mm"] > base["pos_rms_mm"] * 1.001 and shipped["energy_j"] > soft["energy_j"]
    assert "the policy's base PD alone (PD 8 Hz, max_acc 8/100 (policy's base)) against the shipped PD" in text


def test_residual_env_takes_the_base_pd_options():
    from magwarp.envs.levitation_residual import LevitationResidualEnv

    plain = LevitationEnv(2, magnetics=MAG, action="wrench", device="cpu", seed=1)
    residual = LevitationResidualEnv(2, magnetics=MAG, device="cpu", seed=1, pd_frequency=8.0, pd_max_acc=(8, 100))
    assert (residual.pd_frequency, residual.pd_max_acc) == (8.0, (8.0, 100.0))
    pd = LevitationPD(plain, frequency=8.0, max_acc=(8.0, 100.0))
    obs, _ = plain.reset(seed=3)
    residual.reset(seed=3)
    zero = torch.zeros((2, 6))
    for _ in range(10):
        obs, *_ = plain.step(pd(obs))
        obs_r, *_ = residual.step(zero)
    torch.testing.assert_close(obs_r, obs)
    assert LevitationResidualEnv(1, magnetics=MAG, device="cpu").pd_max_acc == (5.0, 60.0)  # the shipped PD's
    for bad in ((8.0,), (8.0, float("nan")), (0.0, 60.0)):
        with pytest.raises(ValueError, match="max_acc"):
            LevitationResidualEnv(1, magnetics=MAG, device="cpu", pd_max_acc=bad)


def test_benchmark_baseline_alone_measures_energy_and_tracking(coarse_default, tmp_path, capsys):
    out = tmp_path / "pd.json"
    assert bench.main(["--envs", "3", "--steps", "40", "--pd-frequencies", "8", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [(r["controller"], r["action"]) for r in rows] == [("PD 8 Hz", "currents"), ("PD 15 Hz", "currents"),
                                                             ("PD 15 Hz", "wrench")]
    for r in rows:  # the PD hovers: no failure, tens to hundreds of watts, tracking under 1 cm
        assert r["failed"] == 0 and r["compared"] == 3 and 10 < r["loss_w"] < 1000 and 0 < r["pos_rms_mm"] < 10, r
        assert r["energy_j"] == pytest.approx(r["loss_w"] * 40 * 1e-3, rel=1e-9)
    slow, fast = rows[0], rows[1]  # a softer PD spends less and tracks worse in the same worlds
    assert slow["energy_j"] < fast["energy_j"] and slow["pos_rms_mm"] > fast["pos_rms_mm"]
    assert "VERDICT" not in capsys.readouterr().out


def test_verdict_needs_less_energy_and_no_worse_tracking():
    base = {"energy_j": 10.0, "failed": 0.0, "success": 1.0, "pos_rms_mm": 2.0, "rot_rms_mrad": 10.0}
    assert bench.verdict({**base, "energy_j": 9.0, "pos_rms_mm": 1.9}, base, "rms", 0.0)[0]
    ok, why = bench.verdict({**base, "energy_j": 9.0, "pos_rms_mm": 2.1}, base, "rms", 0.0)
    assert not ok and "position rms error" in why
    assert bench.verdict({**base, "energy_j": 9.0, "pos_rms_mm": 2.1}, base, "rms", 0.1)[0]
    assert not bench.verdict({**base, "energy_j": 10.5}, base, "rms", 0.0)[0]
    assert not bench.verdict({**base, "energy_j": 9.0, "failed": 0.1}, base, "rms", 0.0)[0]


def test_sweep_verdict_interpolates_the_retuned_pd():
    def pd(hz, pos, energy, rot=10.0):
        return {"frequency_hz": hz, "pos_rms_mm": pos, "energy_j": energy, "rot_rms_mrad": rot, "failed": 0.0}

    sweep = [pd(8, 2.0, 30.0), pd(15, 1.5, 40.0), pd(20, 1.4, 46.0)]
    shipped = sweep[1]
    policy = {"pos_rms_mm": 1.75, "energy_j": 34.0, "rot_rms_mrad": 10.0, "failed": 0.0}  # the PD: 35 J there
    ok, why = bench.sweep_verdict(policy, sweep, shipped, "rms")
    assert ok and "35 J" in why and "between the 15 and 8 Hz" in why
    assert not bench.sweep_verdict({**policy, "energy_j": 35.5}, sweep, shipped, "rms")[0]
    assert not bench.sweep_verdict({**policy, "rot_rms_mrad": 11.0}, sweep, shipped, "rms")[0]
    assert not bench.sweep_verdict({**policy, "failed": 0.1}, sweep, shipped, "rms")[0]
    # beyond the sweep: better tracking than every PD and less energy than the best-tracking one; worse: never
    assert bench.sweep_verdict({**policy, "pos_rms_mm": 1.3, "energy_j": 45.0}, sweep, shipped, "rms")[0]
    assert not bench.sweep_verdict({**policy, "pos_rms_mm": 2.5, "energy_j": 1.0}, sweep, shipped, "rms")[0]


@pytest.mark.parametrize("action", ["wrench", "currents"])
def test_residual_env_with_zero_action_is_the_baseline(action):
    from magwarp.envs.levitation_residual import LevitationResidualEnv

    plain = LevitationEnv(3, magnetics=MAG, action=action, device="cpu", seed=2, max_episode_steps=20)
    residual = LevitationResidualEnv(3, magnetics=MAG, action=action, device="cpu", seed=2, max_episode_steps=20)
    pd = LevitationPD(plain)
    obs, _ = plain.reset(seed=5)
    obs_r, _ = residual.reset(seed=5)
    zero = torch.zeros((3, *residual.single_action_space.shape))
    for _ in range(25):  # through an autoreset
        obs, reward, *_ = plain.step(pd(obs))
        obs_r, reward_r, *_ = residual.step(zero)
        torch.testing.assert_close(obs_r, obs)
        torch.testing.assert_close(reward_r, reward)
    # a correction moves the mover: +1 on the vertical force lifts it above the baseline's path
    lift = zero.clone()
    if action == "wrench":
        lift[:, 2] = 1.0
        for _ in range(5):
            obs, *_ = plain.step(pd(obs))
            obs_r, *_ = residual.step(lift)
        assert torch.all(obs_r[:, 2] > obs[:, 2] + 1e-5)
    with pytest.raises(ValueError, match="residual_scale"):
        LevitationResidualEnv(1, magnetics=MAG, device="cpu", residual_scale=0.0)


def test_ppo_presets_of_the_levitation_family():
    from magwarp.training import ppo

    def resolved(env_id, *extra):
        return ppo.resolve_args(ppo.parse_args(["--env-id", env_id, "--device", "cpu", "--minutes", "1", *extra]))

    for env_id in ("magwarp/Levitation-v0", "magwarp/LevitationWrench-v0", "magwarp/LevitationHover-v0"):
        args = resolved(env_id)
        assert (args.num_envs, args.num_steps, args.gamma, args.hidden, args.init_log_std) == (
            4096, 32, 0.99, "256,256", -2.0)
        assert args.lr == ppo.PRESETS["default"]["lr"]  # the rest from the default row
    args = resolved("magwarp/LevitationResidual-v0")  # its own row, before the family's
    assert (args.num_envs, args.init_log_std, args.lr, args.desired_kl) == (4096, -3.0, 5e-5, 0.005)
    args = resolved("magwarp/LevitationResidual-v0", "--num-envs", "64", "--init-log-std", "-1")
    assert args.num_envs == 64 and args.init_log_std == -1.0  # the command line wins


def test_verdicts_ask_for_a_margin_of_energy():
    base = {"energy_j": 10.0, "failed": 0.0, "success": 1.0, "pos_rms_mm": 2.0, "rot_rms_mrad": 10.0,
            "frequency_hz": 15.0}
    slightly = {**base, "energy_j": 9.95}
    assert bench.verdict(slightly, base, "rms", 0.0)[0] and not bench.verdict(slightly, base, "rms", 0.0, 0.01)[0]
    assert bench.verdict({**base, "energy_j": 9.8}, base, "rms", 0.0, 0.01)[0]
    sweep = [{**base, "frequency_hz": 8.0, "pos_rms_mm": 3.0, "energy_j": 8.0}, base]
    assert not bench.sweep_verdict({**slightly, "pos_rms_mm": 2.0}, sweep, base, "rms", 0.01)[0]
    assert bench.sweep_verdict({**slightly, "pos_rms_mm": 2.0}, sweep, base, "rms", 0.0)[0]


def test_residual_env_scripted_policy_is_the_zero_correction():
    """``magwarp eval LevitationResidual --policy scripted`` runs the PD alone (not the PD as a correction to
    itself)."""
    from magwarp.envs.levitation_residual import LevitationResidualEnv

    env = LevitationResidualEnv(2, magnetics=MAG, device="cpu", seed=0)
    obs, _ = env.reset(seed=0)
    assert torch.equal(env.scripted_policy()(obs), torch.zeros(2, *env.single_action_space.shape))
