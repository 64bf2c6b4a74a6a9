"""SAC's update options (:mod:`magwarp.training.sac_networks`): the ensemble critic and fused Adam follow the two-MLP
critic with foreach Adam update for update (eager, CPU, float32 rounding), and checkpoints of either critic layout
load into the other (weights and Adam moments), so a run saved before the ensemble resumes."""

from __future__ import annotations

import copy

import pytest
import torch

from magwarp.training import sac_her
from magwarp.training.sac_networks import convert_critic_optimizer, convert_critic_state

TINY_ENV = "magwarp/TrajectoryPlanning-v0"
TINY_KWARGS = '{"layout": [[1, 1, 1], [1, 1, 1]], "num_movers": 1}'
N_OBS, N_ACT = 6, 2


def _learner(*extra: str, seed: int = 0) -> sac_her.SacLearner:
    args = sac_her.resolve_args(sac_her.parse_args(["--env-id", TINY_ENV, "--device", "cpu", "--total-steps", "1",
                                                    "--hidden", "32,32", "--lr", "3e-3", *extra]))
    torch.manual_seed(seed)
    return sac_her.SacLearner(N_OBS, N_ACT, args, torch.device("cpu"))


def _sample(n: int, seed: int, demo: bool = False) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    out = {}
    for k, d in (("achieved_goal", 2), ("desired_goal", 2), ("observation", 2)):
        out[k], out["next_" + k] = torch.randn(n, d, generator=g), torch.randn(n, d, generator=g)
    out["action"] = torch.rand(n, N_ACT, generator=g) * 2 - 1
    out["reward"] = -torch.rand(n, generator=g)
    out["terminated"] = torch.rand(n, generator=g) < 0.1
    if demo:
        out["demo"] = (torch.rand(n, generator=g) < 0.5).float()
    return out


def _pair_weights(learner) -> dict[str, torch.Tensor]:
    """Actor, critic and target critic weights and the temperature, the critics in the two-MLP layout."""
    out = {f"actor.{k}": v for k, v in learner.actor.state_dict().items()}
    for name in ("critic", "critic_target"):
        for k, v in convert_critic_state(getattr(learner, name).state_dict(), "pair").items():
            out[f"{name}.{k}"] = v
    out["log_alpha"] = learner.log_alpha.detach()
    return {k: v.clone() for k, v in out.items()}


def _train(learner, seeds, demo: bool = False) -> list[dict[str, float]]:
    losses = []
    for s in seeds:
        torch.manual_seed(100 + s)  # the actor's sampling noise: the same draws for every learner
        losses.append({k: float(v) for k, v in learner.learn(_sample(4 * 64, s, demo), 4).items()})
    return losses


def test_ensemble_critic_starts_as_the_pair_and_its_state_converts_both_ways():
    pair, ens = _learner("--critic-impl", "pair"), _learner("--critic-impl", "ensemble")
    p, e = pair.critic.state_dict(), ens.critic.state_dict()
    assert list(p)[:2] == ["q1.0.weight", "q1.0.bias"] and e["net.0.weight"].shape == (2, N_OBS + N_ACT, 32)
    assert all(torch.equal(v, convert_critic_state(e, "pair")[k]) for k, v in p.items())  # the same draws
    assert all(torch.equal(v, convert_critic_state(p, "ensemble")[k]) for k, v in e.items())
    # the critics compute the same Q values (float rounding: a batched matmul against two)
    xa = torch.randn(16, N_OBS + N_ACT)
    q_pair, q_ens = pair.critic(xa), ens.critic(xa)
    assert q_ens.shape == (2, 16)
    torch.testing.assert_close(q_ens, torch.stack(q_pair), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="not a SAC critic state"):
        convert_critic_state({"w": torch.zeros(1)}, "pair")


@pytest.mark.parametrize("demo", [False, True])
def test_ensemble_critic_and_fused_adam_follow_the_pair_with_foreach_adam(demo):
    """The old update (two MLPs, foreach Adam) and the ensemble with fused Adam, from the same weights and the
    same noise: the same losses and weights after 8 updates (2 with the actor and temperature each) within float32
    rounding; every option combination too."""
    bc = ("--demo-bc", "0.5", "--demo-episodes", "1") if demo else ()
    ref = _learner("--critic-impl", "pair", "--adam", "foreach", "--policy-delay", "2", *bc)
    assert not ref.critic_opt.param_groups[0]["fused"]
    w0 = _pair_weights(ref)
    ref_losses = _train(ref, range(2), demo)
    ref_w = _pair_weights(ref)
    for impl, adam in (("ensemble", "fused"), ("ensemble", "foreach"), ("pair", "fused")):
        new = _learner("--critic-impl", impl, "--adam", adam, "--policy-delay", "2", *bc)
        assert new.critic_opt.param_groups[0]["fused"] == (adam == "fused")
        assert all(torch.equal(v, _pair_weights(new)[k]) for k, v in w0.items())
        losses = _train(new, range(2), demo)
        for a, b in zip(ref_losses, losses):
            assert b == pytest.approx(a, rel=1e-4, abs=1e-6), (impl, adam)
        w = _pair_weights(new)
        moved = max(float((ref_w[k] - w0[k]).abs().max()) for k in w0)
        assert moved > 1e-3  # the weights did move (lr 3e-3, 8 critic updates)
        for k, v in ref_w.items():
            torch.testing.assert_close(w[k], v, rtol=1e-4, atol=2e-5, msg=f"{impl}/{adam}: {k}")
        steps = float(next(iter(new.critic_opt.state.values()))["step"])
        assert steps == 8.0 and float(next(iter(new.alpha_opt.state.values()))["step"]) == 4.0


@pytest.mark.parametrize("saved, loaded", [("pair", "ensemble"), ("ensemble", "pair")])
def test_a_checkpoint_of_either_critic_layout_resumes_in_the_other(saved, loaded):
    """Weights and Adam moments convert: the resumed learner continues as the saver does."""
    src = _learner("--critic-impl", saved)
    _train(src, range(2))
    state = copy.deepcopy(src.state_dict())  # as from a file (a loaded optimiser may share the saver's step tensors)
    assert set(convert_critic_optimizer(state["critic_opt"], saved, saved)["state"]) == set(
        state["critic_opt"]["state"])
    dst = _learner("--critic-impl", loaded, seed=7)
    dst.load_state_dict(state)
    assert dst.critic_opt.param_groups[0]["fused"] and len(dst.critic_opt.state) == len(list(dst.critic.parameters()))
    before = _pair_weights(src)
    assert all(torch.equal(v, _pair_weights(dst)[k]) for k, v in before.items())
    a, b = _train(src, [5]), _train(dst, [5])
    assert b[0] == pytest.approx(a[0], rel=1e-4, abs=1e-6)
    for k, v in _pair_weights(src).items():
        torch.testing.assert_close(_pair_weights(dst)[k], v, rtol=1e-4, atol=2e-5, msg=k)


def test_a_broken_critic_state_names_the_file():
    learner = _learner()
    learner.args.resume = "runs/old/checkpoint.pt"
    state = learner.state_dict()
    state["critic"] = {"layer.weight": torch.zeros(2)}
    with pytest.raises(ValueError, match=r"runs/old/checkpoint.pt.*not a SAC critic state"):
        learner.load_state_dict(state)


def test_a_two_mlp_run_resumes_with_the_ensemble(tmp_path):
    """A run written with ``--critic-impl pair`` (the layout of checkpoints before the option), its option removed
    from the checkpoint as an old one lacks it: ``--resume`` with ``--critic-impl ensemble`` converts it and trains
    on."""
    common = ["--env-id", TINY_ENV, "--env-kwargs", TINY_KWARGS, "--device", "cpu", "--num-envs", "8",
              "--batch-size", "32", "--hidden", "16,16", "--learning-starts", "2", "--buffer-steps", "16",
              "--updates-per-step", "2", "--no-progress", "--eval-steps", "0", "--log-every", "1000"]
    sac_her.train(sac_her.parse_args([*common, "--critic-impl", "pair", "--adam", "foreach", "--out", str(tmp_path),
                                      "--total-steps", "48"]))
    path = tmp_path / "checkpoint.pt"
    ckpt = torch.load(path, weights_only=False)
    assert "q1.0.weight" in ckpt["critic"]
    for k in ("critic_impl", "adam", "amp"):
        del ckpt["args"][k]
    torch.save(ckpt, path)
    summary = sac_her.train(sac_her.parse_args(["--resume", str(tmp_path), "--total-steps", "96", "--no-progress",
                                                        "--critic-impl", "ensemble"]))
    assert summary["global_step"] == 96
    resumed = torch.load(path, weights_only=False)
    assert "net.0.weight" in resumed["critic"] and resumed["args"]["critic_impl"] == "ensemble"
    assert resumed["updates"] > ckpt["updates"]


def test_compiled_losses_follow_the_eager_ones():
    """``--compile on`` (torch.compile of both losses; the actor's noise from torch's generator as eagerly)."""
    eager, compiled = _learner("--policy-delay", "2"), _learner("--policy-delay", "2", "--compile", "on")
    a, b = _train(eager, range(2)), _train(compiled, range(2))
    for x, y in zip(a, b):
        assert y == pytest.approx(x, rel=1e-5, abs=1e-6)
    for k, v in _pair_weights(eager).items():
        torch.testing.assert_close(_pair_weights(compiled)[k], v, rtol=1e-5, atol=1e-6, msg=k)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a GPU")
@pytest.mark.parametrize("options", [("--critic-impl", "pair", "--adam", "foreach"), ("--amp", "bf16")])
def test_graphed_updates_match_eager_ones_for_every_option(options):
    """As ``test_training.py``'s graphed test (the defaults), for the other critic and optimiser and for bf16."""
    weights = {}
    for mode in ("off", "on"):
        args = sac_her.resolve_args(sac_her.parse_args(["--env-id", TINY_ENV, "--device", "cuda", "--total-steps", "1",
                                                        "--hidden", "32,32", "--cuda-graph", mode, *options]))
        torch.manual_seed(0)
        learner = sac_her.SacLearner(N_OBS, N_ACT, args, torch.device("cuda"))
        assert learner.graphed == (mode == "on")
        torch.manual_seed(1)
        for seed in range(3):  # the first call captures, the later ones replay on freshly staged minibatches
            sample = {k: v.cuda() for k, v in _sample(8 * 64, seed).items()}
            losses = learner.learn(sample, 8)
        torch.cuda.synchronize()
        weights[mode] = {k: v.cpu() for k, v in _pair_weights(learner).items()}
        assert all(torch.isfinite(v) for v in losses.values())
    for k, v in weights["off"].items():
        torch.testing.assert_close(weights["on"][k], v, atol=1e-4, rtol=1e-3, msg=k)
