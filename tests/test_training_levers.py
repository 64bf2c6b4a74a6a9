"""The training levers of the time-to-target work on the CPU, a couple of iterations each: tanh-squashed PPO (its
log-probability against torch.distributions and a numpy reference), bf16 autocast, torch.compile, the phase profile,
the CUDA-graph option's refusal on the CPU (and, on a CUDA machine, graphed PPO updates equal to eager ones), B0's
collision criterion of the time to target, --past-target, and the plumbing of benchmarks/time_to_target.py."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from magwarp.training import ppo

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

TINY_ENV = "magwarp/TrajectoryPlanning-v0"
TINY_KWARGS = '{"layout": [[1, 1, 1], [1, 1, 1], [1, 1, 1]], "num_movers": 1}'
N, T = 16, 8  # one PPO iteration: 128 env steps


def _args(out, *extra):
    return ppo.parse_args(["--env-id", TINY_ENV, "--env-kwargs", TINY_KWARGS, "--device", "cpu", "--seed", "3",
                           "--num-envs", str(N), "--num-steps", str(T), "--num-minibatches", "2", "--update-epochs",
                           "2", "--hidden", "16,16", "--out", str(out), "--no-progress", "--log-every", "1000",
                           "--eval-steps", "4", *extra])


def test_tanh_log_prob_matches_torch_distributions_and_numpy(rng):
    mean = torch.as_tensor(rng.normal(0.0, 1.0, (64, 3)))
    log_std = torch.as_tensor(rng.uniform(-2.0, 0.5, (64, 3)))
    u = torch.as_tensor(rng.normal(0.0, 2.0, (64, 3)))
    got = ppo.squashed_log_prob(mean, log_std, u, "tanh")
    from torch.distributions import Normal, TanhTransform, TransformedDistribution

    squashed = TransformedDistribution(Normal(mean, log_std.exp()), [TanhTransform(cache_size=1)])
    want = squashed.log_prob(torch.tanh(u)).sum(-1)  # the cache hands back u: no atanh round trip
    torch.testing.assert_close(got, want, rtol=1e-9, atol=1e-9, msg=str(rng))
    # numpy: log N(u; mean, std) - log(1 - tanh(u)^2), per dimension, in float64
    m, s, x = mean.numpy(), np.exp(log_std.numpy()), u.numpy()
    ref = (-0.5 * ((x - m) / s) ** 2 - np.log(s) - 0.5 * math.log(2 * math.pi) - np.log1p(-np.tanh(x) ** 2)).sum(-1)
    np.testing.assert_allclose(got.numpy(), ref, rtol=1e-7, atol=1e-7, err_msg=str(rng))
    # clip: the Gaussian's own density of u
    torch.testing.assert_close(ppo.squashed_log_prob(mean, log_std, u, "clip"),
                               Normal(mean, log_std.exp()).log_prob(u).sum(-1), msg=str(rng))


def test_tanh_log_prob_stays_finite_where_tanh_saturates():
    u = torch.tensor([[30.0, -30.0]])
    lp = ppo.squashed_log_prob(torch.zeros(1, 2), torch.zeros(1, 2), u, "tanh")
    assert torch.isfinite(lp).all()  # log(1 - tanh(u)^2) would be log(0)


@pytest.mark.parametrize("extra", [("--squash", "tanh"), ("--amp", "bf16"), ("--profile",)], ids=lambda e: e[-1])
def test_ppo_lever_runs_two_iterations(tmp_path, extra):
    summary = ppo.train(_args(tmp_path, "--total-steps", str(2 * N * T), *extra))
    assert summary["global_step"] == 2 * N * T
    policy = torch.jit.load(str(tmp_path / "policy.pt"), map_location="cpu")
    action = policy(torch.randn(5, policy.obs_dim) * 3)
    assert torch.isfinite(action).all() and float(action.abs().max()) <= 10.0 + 1e-5
    assert policy.flat.use_tanh == ("tanh" in extra)
    if "--profile" in extra:
        prof = summary["profile"]
        assert {"env", "policy", "update", "log"} <= set(prof)
        assert all(v["s"] > 0 and v["calls"] > 0 for k, v in prof.items() if k != "log")
        assert prof["env"]["calls"] == 2 * T and prof["update"]["calls"] == 2
        assert abs(sum(v["share"] for v in prof.values()) - 1.0) < 1e-3
        assert json.loads((tmp_path / "run.json").read_text())["summary"]["profile"]["env"]["calls"] == 2 * T


def test_ppo_compile_runs_two_iterations(tmp_path):
    pytest.importorskip("torch._inductor")
    summary = ppo.train(_args(tmp_path, "--total-steps", str(2 * N * T), "--compile", "on"))
    assert summary["global_step"] == 2 * N * T and math.isfinite(summary["eval_success_rate"])


def test_cuda_graph_on_needs_cuda(tmp_path):
    if torch.cuda.is_available():
        pytest.skip("a CUDA machine: the option is valid")
    with pytest.raises(ValueError, match="needs a CUDA device"):
        ppo.train(_args(tmp_path, "--total-steps", "128", "--cuda-graph", "on"))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a CUDA device")
@pytest.mark.parametrize("squash", ["clip", "tanh"])
def test_graphed_ppo_updates_match_eager_ones(squash):
    """The same rollout and minibatch order: the graphed update (3 eager warm-up steps, then replays) gives the
    eager update's weights."""
    results = []
    precision = torch.get_float32_matmul_precision()
    torch.set_float32_matmul_precision("highest")  # no TF32: cuBLAS may pick other kernels inside a capture
    for graph in ("off", "on"):
        torch.manual_seed(0)
        args = argparse.Namespace(num_envs=64, num_steps=8, num_minibatches=4, update_epochs=3, cuda_graph=graph,
                                  compile="off", clip_coef=0.2, vf_coef=1.0, ent_coef=0.0, max_grad_norm=1.0)
        agent = ppo.Agent(6, 2, [32, 32], -0.5, squash).cuda()
        opt = torch.optim.Adam(agent.parameters(), lr=3e-4, eps=1e-5)
        update = ppo.PpoUpdate(agent, opt, args, "cuda", 6, 2)
        g = torch.Generator("cuda").manual_seed(1)
        data = {"obs": torch.randn(8, 64, 6, device="cuda", generator=g),
                "act": torch.randn(8, 64, 2, device="cuda", generator=g),
                "logp": torch.randn(8, 64, device="cuda", generator=g) - 2,
                **{k: torch.randn(8, 64, device="cuda", generator=g) for k in ("adv", "ret", "val")}}
        for _ in range(2):
            torch.manual_seed(5)  # the minibatch permutation
            kl, _, _ = update.run(data)
        results.append(([p.detach().clone() for p in agent.parameters()], float(kl)))
    torch.set_float32_matmul_precision(precision)
    (eager, kl_eager), (graphed, kl_graphed) = results
    for a, b in zip(eager, graphed):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
    assert kl_graphed == pytest.approx(kl_eager, rel=1e-3, abs=1e-7)


def _target_eval(max_collisions):
    from magwarp.training.loop import TargetEval

    args = argparse.Namespace(target=0.99, target_collisions=max_collisions, eval_every=0.0)
    return TargetEval(args, "cpu")


def test_target_needs_few_collisions_where_set():
    ev = {"success_rate": 0.995, "collisions_per_1k_goals": 2.5}
    assert _target_eval(None).met(ev) and _target_eval(0).met(ev)  # no collision criterion
    assert not _target_eval(2.14).met(ev)
    assert _target_eval(2.14).met({**ev, "collisions_per_1k_goals": 1.9})
    assert not _target_eval(2.14).met({**ev, "success_rate": 0.98, "collisions_per_1k_goals": 0.0})
    assert not _target_eval(2.14).met({**ev, "collisions_per_1k_goals": float("nan")})
    from magwarp.training.loop import default_target_collisions

    assert default_target_collisions("magwarp/TrajectoryPlanningB0-v0") == 2.14
    assert default_target_collisions("magwarp/PushBox-v0") is None
    with pytest.raises(ValueError, match="--target-collisions"):
        ppo.resolve_args(ppo.parse_args(["--env-id", TINY_ENV, "--minutes", "1", "--target-collisions", "nan"]))


def test_train_command_writes_time_to_target_with_collisions(tmp_path, capsys):
    """`magwarp train` on a tiny task: the first crossing (success and collisions) is printed and in run.json."""
    from magwarp.cli import main

    out = tmp_path / "run"
    argv = ["train", TINY_ENV, "--algo", "ppo", "--device", "cpu", "--num-envs", "16", "--total-steps", "512",
            "--out", str(out), "--env-kwargs", TINY_KWARGS, "--target", "0.01", "--args",
            "--num-steps 8 --hidden 16,16 --eval-every 1e-9 --eval-envs 8 --target-eval-steps 60 "
            "--target-collisions 1e6"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "time to target: success" in text and "< 1e+06 collisions per 1000 goals" in text
    run = json.loads((out / "run.json").read_text())
    s = run["summary"]
    assert s["target"] == 0.01 and s["target_collisions"] == 1e6
    assert s["time_to_target_s"] == run["evals"][0]["process_s"] > 0
    assert all("collisions_per_1k_goals" in e for e in run["evals"])


@pytest.mark.parametrize("past", [0.0, 1e9])
def test_past_target_keeps_training_after_the_crossing(tmp_path, past):
    summary = ppo.train(_args(tmp_path, "--total-steps", str(4 * N * T), "--target", "0.001", "--eval-every", "1e-9",
                              "--eval-envs", "8", "--target-eval-steps", "60", "--stop-at-target", "--past-target",
                              str(past)))
    assert summary["time_to_target_step"] == N * T  # the first evaluation crossed
    assert summary["global_step"] == (N * T if past == 0 else 4 * N * T)


def test_time_to_target_benchmark_plumbing(tmp_path):
    import time_to_target as ttt

    cmd = ttt.training_command(ttt.TASKS["b0"], 2, 90.0, "cuda:0", tmp_path, ["--num-envs", "8"], True, False)
    assert cmd[cmd.index("--seed") + 1] == "2" and cmd[cmd.index("--stop-after") + 1] == "90"
    assert "--stop-at-target" in cmd and cmd[-2:] == ["--num-envs", "8"]
    assert "--stop-at-target" not in ttt.training_command(ttt.TASKS["b0"], 0, 90.0, "cpu", tmp_path, [], False, False)
    rows = [{"task": "b0", "exit": 0, "budget_s": 90, "confirmed": ok, "time_to_target_s": t, "eval_success_pct": p,
             "eval_collisions_per_1k": c, "target": 0.99, "target_collisions": 2.14}
            for ok, t, p, c in ((True, 52.0, 99.5, 1.4), (True, 70.0, 99.3, 1.9), (False, None, 98.9, 2.5),
                                (False, None, 99.2, 2.0))]  # the last: no periodic crossing, the policy meets it
    (row,) = ttt.summary_rows(rows)
    assert row["confirmed"] == "2/4" and row["met_at_budget"] == "3/4"
    assert [ttt.meets_target(r) for r in rows] == [True, True, False, True]
    rows.pop()
    (row,) = ttt.summary_rows(rows)
    assert row["confirmed"] == "2/3" and row["median_ttt_s"] == 70.0 and row["ttt_min_max_s"] == "52-70"
    assert row["eval_success_pct"] == 99.3 and row["eval_collisions_per_1k"] == 1.9
    rows[1]["confirmed"] = False  # two of three missed: the median is a miss
    assert ttt.summary_rows(rows)[0]["median_ttt_s"] is None
