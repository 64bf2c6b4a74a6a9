"""Sim2real models on the mujoco-warp push envs (magwarp.envs.sim2real.PushSim2Real): action latency delays the
action by exactly k control cycles per world (logged cycle by cycle inside the step graph), delays drawn at resets
reproduce, sensor bias/noise/dropout on the mover readings; object size terms (magwarp.envs.randomization) are
object_ranges with the same draws for the same seed."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from magwarp.envs.push import PushBoxEnv
from magwarp.envs.randomization import EventTerm, Uniform
from magwarp.envs.sim2real import ActuationConfig, SensorConfig


@wp.kernel
def _log_acc(cycle: int, acc: wp.array2d(dtype=wp.vec2), log: wp.array3d(dtype=wp.vec2)):
    w, m = wp.tid()
    log[cycle, w, m] = acc[w, m]


def test_latency_delays_actions_by_exactly_k_cycles():
    delays = [0, 1, 7, 40]
    env = PushBoxEnv(4, device="cpu", seed=0, actuation=ActuationConfig(latency_cycles=delays))
    env.reset()
    n = env.num_cycles
    per_step = []
    actions = [torch.full((4, 2), 0.5), torch.full((4, 2), -0.3), torch.tensor([[0.2, -0.1]]).repeat(4, 1)]
    buf = wp.zeros((n, 4, 1), dtype=wp.vec2, device="cpu")
    state = {"k": 0}

    def hook():
        c = state["k"] % n
        state["k"] += 1
        wp.launch(_log_acc, dim=(4, 1), inputs=[c, env.backend.acc, buf], device="cpu")

    env.backend.add_cycle_hook(hook)
    for a in actions:
        env.step(a)
        per_step.append(buf.numpy().copy())
    prev = torch.zeros(4, 2)
    for a, log in zip(actions, per_step):
        for w, k in enumerate(delays):
            expect = np.concatenate([np.repeat(prev[w][None].numpy(), k, 0), np.repeat(a[w][None].numpy(), n - k, 0)])
            np.testing.assert_allclose(log[:, w, 0], expect, rtol=1e-6, atol=1e-7, err_msg=f"world {w}, delay {k}")
        prev = a


def test_latency_range_draws_per_reset_and_reproduces():
    def delays(seed):
        env = PushBoxEnv(64, device="cpu", seed=seed, actuation={"latency_range": [2, 6]})
        return env.latency.delay.clone(), env

    d1, env = delays(5)
    d2, _ = delays(5)
    assert torch.equal(d1, d2) and d1.min() >= 2 and d1.max() <= 6 and len(set(d1.tolist())) == 5
    mask = torch.zeros(64, dtype=torch.bool)
    mask[:10] = True
    env.reset(options={"reset_mask": mask})
    assert torch.equal(env.latency.delay[10:], d1[10:]) and not torch.equal(env.latency.delay[:10], d1[:10])
    with pytest.raises(ValueError, match="exceeds num_cycles=40"):
        PushBoxEnv(2, device="cpu", actuation=ActuationConfig(latency_cycles=41))


def test_sensors_bias_noise_and_dropout():
    env = PushBoxEnv(256, device="cpu", seed=1, sensors=SensorConfig(pos_bias=(0.01, -0.02), vel_noise_std=0.05))
    obs, _ = env.reset()
    b = env.backend
    true_xy = b.mover_qpos[:, 0, :2]
    np.testing.assert_allclose((obs["observation"][:, :2] - true_xy).numpy(), np.tile([0.01, -0.02], (256, 1)),
                               atol=1e-6)
    vel_noise = obs["observation"][:, 2:4] - b.mover_qvel[:, 0, :2]
    assert abs(float(vel_noise.std()) - 0.05) < 0.006
    drop = PushBoxEnv(64, device="cpu", seed=2, sensors={"dropout_prob": 0.5})
    o0, _ = drop.reset()
    o1 = drop.step(torch.full((64, 2), 1.0))[0]
    same = (o1["observation"] == o0["observation"]).all(1) & (o1["achieved_goal"] == o0["achieved_goal"]).all(1)
    assert 10 < int(same.sum()) < 54
    with pytest.raises(ValueError, match="give std_noise or sensors"):
        PushBoxEnv(2, device="cpu", std_noise=0.01, sensors={"pos_noise_std": 0.01})


def test_object_size_terms_are_object_ranges():
    terms = [EventTerm("object_width", Uniform(0.04, 0.06)), EventTerm("object_height", Uniform(0.05, 0.05))]
    a = PushBoxEnv(8, device="cpu", seed=3, object_variants=4, randomization=terms)
    b = PushBoxEnv(8, device="cpu", seed=3, object_variants=4,
                   object_ranges={"width": (0.04, 0.06), "height": (0.05, 0.05)})
    assert [s.width for s in a.variants.specs] == [s.width for s in b.variants.specs]
    assert torch.equal(a.object_variant, b.object_variant)
    assert a.object.height == 0.05 and a.randomizer is None
    # with size terms, the object's mass term is object_ranges' "mass" (the same variants and draws)
    terms_m = terms + [EventTerm("object_mass", Uniform(0.2, 0.4))]
    c = PushBoxEnv(8, device="cpu", seed=3, object_variants=4, randomization=terms_m)
    d = PushBoxEnv(8, device="cpu", seed=3, object_variants=4,
                   object_ranges={"width": (0.04, 0.06), "height": (0.05, 0.05), "mass": (0.2, 0.4)})
    assert [s.mass for s in c.variants.specs] == [s.mass for s in d.variants.specs]
    assert len({s.mass for s in c.variants.specs}) == 4 and c.randomizer is None
    assert torch.equal(c.object_variant, d.object_variant)
    with pytest.raises(ValueError, match="object_mass.*uniform.*'set'.*'reset'"):
        PushBoxEnv(2, device="cpu", randomization=terms + [EventTerm("object_mass", Uniform(0.2, 0.4), mode="startup")])
    with pytest.raises(ValueError, match="object_width.*uniform.*'set'.*'reset'"):
        PushBoxEnv(2, device="cpu", randomization=[EventTerm("object_width", Uniform(0.9, 1.1), op="scale")])
    with pytest.raises(ValueError, match="not both object_ranges="):
        PushBoxEnv(2, device="cpu", object_ranges={"width": (0.04, 0.06)}, randomization=terms)
