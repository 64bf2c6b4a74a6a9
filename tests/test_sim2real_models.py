"""Sim2real actuation and sensing models (magwarp.envs.sim2real): action latency in the simulator's step kernels
(every launch shape, against a simulator stepping the delayed commands cycle by cycle), latency 0 bit for bit,
sensor bias and noise moments, seeded draws, dropped readings, and errors that name the bad option."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp.envs.sim2real import ActuationConfig, SensorConfig, draw_key
from magwarp.envs.trajectory import TrajectoryPlanningEnv
from magwarp.kernels import sensor_draws as kdraw
from magwarp.layout import Layout
from magwarp.sim import Simulator

from conftest import cuda_available
from test_sensor_draws import fill_normals

# launch shapes: register-resident fused (M <= 8), fused from memory (M <= 16), per cycle (fused_max_movers=0)
PATHS = {"registers": (3, 16), "fused": (10, 16), "per_cycle": (3, 0)}


def spaced_sim(num_movers: int, num_worlds: int, fused_max_movers: int, control: str = "acceleration",
               device: str = "cpu"):
    """Movers on every other tile of a large layout, no stop on collision (the per-cycle reference restarts its
    per-step accumulators every cycle, so the comparison must not depend on them)."""
    layout = Layout.grid(8, 6)
    centres = layout.tile_centers()
    starts = centres[np.arange(num_movers) * (len(centres) // num_movers)]
    return Simulator(layout, num_movers, num_worlds, start_xy=starts, device=device, control=control,
                     fused_max_movers=fused_max_movers, stop_on_collision=False)


@pytest.mark.parametrize("device", ["cpu"] + (["cuda:0"] if cuda_available() else []))
@pytest.mark.parametrize("control", ["acceleration", "jerk"])
@pytest.mark.parametrize("path", list(PATHS))
def test_latency_delays_commands_by_exactly_k_cycles(path, control, device, rng):
    m, fused_max = PATHS[path]
    n, worlds = 7, 5
    delays = np.array([0, 1, 3, 6, 7])  # 0 and num_cycles included
    sim = spaced_sim(m, worlds, fused_max, control, device)
    ref = spaced_sim(m, worlds, fused_max, control, device)
    dev = sim.torch_device
    sim.set_latency(torch.as_tensor(delays, device=dev))
    assert torch.equal(sim.latency_cycles.cpu(), torch.as_tensor(delays, dtype=torch.int32))
    assert sim.latency_bound == 7
    prev = torch.zeros(worlds, m, 2, device=dev)
    scale = 4.0 if control == "acceleration" else 60.0
    for t in range(4):
        cmd = torch.as_tensor(rng.normal(size=(worlds, m, 2)) * scale, dtype=torch.float32, device=dev)
        sim.step(n, cmd)
        for c in range(n):  # the reference: one cycle at a time, each world's delayed command
            late = torch.as_tensor(c < delays, device=dev)[:, None, None]
            ref.step(1, torch.where(late, prev, cmd))
        prev = cmd
        for name in ("pos", "vel", "quat", "acc"):
            got, want = getattr(sim, name), getattr(ref, name)
            if device == "cpu":  # the CPU compiles both launch shapes alike: bit for bit
                assert torch.equal(got, want), f"{rng} {path} {control} step {t}: {name}"
            else:  # CUDA may contract floating-point operations differently per kernel
                torch.testing.assert_close(got, want, atol=1e-6, rtol=1e-6, msg=f"{rng} {path} {control} {t}: {name}")
        assert torch.equal(sim.prev_cmd, cmd), "the step's command becomes the next step's previous one"
        if t == 1:  # a reset world starts at rest: its previous command is zero
            mask = torch.tensor([True, False, True, False, True], device=dev)
            sim.reset(mask)
            ref.reset(mask)
            prev = torch.where(mask[:, None, None], 0.0, prev)
    assert len(sim._graphs) == 1, "one graph per step"
    dump = sim.state_arrays([3])
    assert dump["latency_cycles"].tolist() == [6] and np.array_equal(dump["prev_cmd"], sim.prev_cmd[3:4].cpu().numpy())


def test_latency_zero_steps_bit_for_bit_and_can_be_turned_off(rng):
    plain, late = spaced_sim(3, 4, 16), spaced_sim(3, 4, 16)
    late.set_latency(0)
    for _ in range(3):
        cmd = torch.as_tensor(rng.normal(size=(4, 3, 2)) * 5.0, dtype=torch.float32)
        plain.step(9, cmd)
        late.step(9, cmd)
        for name in ("pos", "vel", "quat", "acc"):
            assert torch.equal(getattr(plain, name), getattr(late, name)), f"{rng}: {name}"
    late.set_latency(None)
    assert late.latency_cycles is None and late.prev_cmd is None and late.latency_bound is None
    late.step(2, torch.ones(4, 3, 2))  # any step length again


def test_env_latency_zero_equals_todays_env_bit_for_bit(rng):
    kw = dict(device="cpu", seed=int(rng.integers(1 << 30)), sensors=None)
    envs = [TrajectoryPlanningEnv(8, "B0", **kw), TrajectoryPlanningEnv(8, "B0", actuation=ActuationConfig(
        latency_range=(0, 0)), **kw)]
    assert envs[1].sim.latency_bound == 0 and envs[0].sim.latency_bound is None
    for t in range(6):
        action = torch.as_tensor(rng.uniform(-10, 10, size=(8, 6)), dtype=torch.float32)
        outs = [env.step(action) for env in envs]
        for key in ("observation", "achieved_goal", "desired_goal"):
            assert torch.equal(outs[0][0][key], outs[1][0][key]), f"{rng} step {t}: {key}"
        assert torch.equal(outs[0][1], outs[1][1])


def test_env_latency_per_world_in_the_first_step():
    """From rest, with acceleration a held after a delay k: v = a (n - k) dt after the step; k = n leaves the world at
    rest until the next step, which applies the held action for k cycles first."""
    n = 20
    delays = [0, 5, 13, 20]
    env = TrajectoryPlanningEnv(4, "B0", num_cycles=n, device="cpu", seed=0,
                                actuation=ActuationConfig(latency_cycles=delays))
    action = torch.zeros(4, 6)
    action[:, 0] = 2.0  # mover 0, +x, m/s^2
    env.step(action)
    vx = env.sim.vel[:, 0, 0].numpy()
    np.testing.assert_allclose(vx, [2.0 * (n - k) * 1e-3 for k in delays], rtol=1e-5, atol=1e-9)
    assert not env.sim.vel[:, 1:, :2].any(), "the other movers had no command"
    env.step(torch.zeros(4, 6))  # the first action acts k more cycles, then nothing
    np.testing.assert_allclose(env.sim.vel[:, 0, 0].numpy(), 2.0 * n * 1e-3, rtol=1e-5)


def test_env_latency_range_draws_uniformly_per_reset_and_reproduces():
    env = TrajectoryPlanningEnv(512, "B0", num_cycles=10, device="cpu", seed=3,
                                actuation={"latency_range": [2, 9]})
    delays = env.sim.latency_cycles.clone()
    assert delays.min() == 2 and delays.max() == 9 and env.sim.latency_bound == 9
    counts = torch.bincount(delays.long(), minlength=10)[2:].float()
    assert (counts - 64).abs().max() < 30, counts  # 512 draws over 8 values
    mask = torch.zeros(512, dtype=torch.bool)
    mask[:256] = True
    env.reset(options={"reset_mask": mask})
    assert torch.equal(env.sim.latency_cycles[256:], delays[256:]), "only reset worlds draw"
    assert not torch.equal(env.sim.latency_cycles[:256], delays[:256])
    again = TrajectoryPlanningEnv(512, "B0", num_cycles=10, device="cpu", seed=3,
                                  actuation=ActuationConfig(latency_range=(2, 9)))
    assert torch.equal(again.sim.latency_cycles, delays)
    env.reset(seed=11)
    again.reset(seed=11)
    assert torch.equal(env.sim.latency_cycles, again.sim.latency_cycles)


@pytest.mark.parametrize("fused", [True, False])
def test_sensor_bias_and_noise_have_the_given_moments(fused):
    n = 1024
    cfg = SensorConfig(pos_bias=(0.01, -0.02), pos_bias_std=0.005, vel_bias=0.003, vel_bias_std=0.002,
                       pos_noise_std=0.002, vel_noise_std=0.001)
    env = TrajectoryPlanningEnv(n, "B0", device="cpu", seed=5, sensors=cfg, fused=fused)
    obs, _ = env.reset(seed=7)
    bias_p, bias_v = env.sensors.pos_bias.clone(), env.sensors.vel_bias.clone()  # [n, 3, 2]
    for bias, mean, std in ((bias_p, (0.01, -0.02), 0.005), (bias_v, (0.003, 0.003), 0.002)):
        np.testing.assert_allclose(bias.mean(dim=(0, 1)).numpy(), mean, atol=4 * std / np.sqrt(3 * n))
        np.testing.assert_allclose(bias.std(dim=(0, 1)).numpy(), std, rtol=0.06)
    for t in range(2):
        pos_err = obs["achieved_goal"] - (env.sim.pos[..., :2] + bias_p).reshape(n, -1)
        vel_err = obs["observation"] - (env.sim.vel[..., :2] + bias_v).reshape(n, -1)
        for err, std in ((pos_err, 0.002), (vel_err, 0.001)):
            assert abs(err.mean().item()) < 4 * std / np.sqrt(err.numel())
            assert err.std().item() == pytest.approx(std, rel=0.05)
        obs, *_ = env.step(torch.zeros(n, 6))  # the bias is constant within an episode, the noise is new
        assert torch.equal(env.sensors.pos_bias, bias_p)
    mask = torch.arange(n) < 100
    env.reset(options={"reset_mask": mask})
    assert torch.equal(env.sensors.pos_bias[100:], bias_p[100:]) and not torch.equal(env.sensors.pos_bias[:100],
                                                                                      bias_p[:100])


def test_set_bias_without_std_is_that_bias_everywhere():
    bias = np.zeros((4, 3, 2), dtype=np.float32)
    bias[2, 1] = (0.05, -0.01)
    env = TrajectoryPlanningEnv(4, "B0", device="cpu", seed=0, sensors=SensorConfig(pos_bias=bias))
    obs, _ = env.reset()
    expected = env.sim.pos[..., :2] + torch.as_tensor(bias)
    assert torch.equal(obs["achieved_goal"], expected.reshape(4, -1))
    assert torch.equal(obs["observation"], env.sim.vel[..., :2].reshape(4, -1)), "no velocity model: exact"


def test_std_noise_draws_are_counter_based_and_equal_the_sensor_config():
    """``std_noise``: a reading outside a step draws its velocity and position noise from the counter-based generator
    (the env's key and draw clock, reading slot pair of the clock: since #24, not the env's torch generator); inside
    steps it draws as the SensorConfig of the same stds."""
    s = 1e-3
    env = TrajectoryPlanningEnv(16, "B0", std_noise=s, device="cpu", seed=4)
    obs, _ = env.reset()  # the 2nd reset outside a step since the seed: clock -2, its first reading
    z = {slot: fill_normals(draw_key(4), -2, slot, 16, 3) for slot in (kdraw.READ, kdraw.READ + 1)}
    vel = env.sim.vel[..., :2].reshape(16, -1) + s * z[kdraw.READ].reshape(16, -1)
    pos = env.sim.pos[..., :2].reshape(16, -1) + s * z[kdraw.READ + 1].reshape(16, -1)
    assert torch.equal(obs["observation"], vel) and torch.equal(obs["achieved_goal"], pos)
    other = TrajectoryPlanningEnv(16, "B0", device="cpu", seed=4,
                                  sensors=SensorConfig(pos_noise_std=s, vel_noise_std=s))
    env.reset(seed=1)
    other.reset(seed=1)
    action = torch.full((16, 6), 3.0)
    for _ in range(3):
        a, b = env.step(action)[0], other.step(action)[0]
        assert all(torch.equal(a[k], b[k]) for k in a)


def test_models_leave_the_goal_and_start_draws_alone():
    """The sensor and latency models draw nothing from the env's generator: goals, starts and episodes of an env
    with every model on are those of an env without them, for the same seed (the movers' poses differ only by the
    delayed actions, so the goals are compared with the latency off)."""
    kw = dict(device="cpu", seed=6, max_episode_steps=3)
    plain = TrajectoryPlanningEnv(64, "B0", **kw)
    noisy = TrajectoryPlanningEnv(64, "B0", sensors=SensorConfig(pos_bias_std=0.01, vel_bias_std=0.01,
                                                                pos_noise_std=1e-3, vel_noise_std=1e-3,
                                                                dropout_prob=0.2), **kw)
    late = TrajectoryPlanningEnv(64, "B0", actuation={"latency_range": [0, 9]}, **kw)
    for env in (plain, noisy, late):
        env.reset(seed=21)
    assert torch.equal(plain.goals, noisy.goals) and torch.equal(plain.sim.pos, noisy.sim.pos)
    assert torch.equal(plain.goals, late.goals) and torch.equal(plain.sim.pos, late.sim.pos)
    for _ in range(7):  # episodes of 3 steps: two autoresets of every world
        for env in (plain, noisy, late):
            env.step(torch.zeros(64, 6))
    assert torch.equal(plain.goals, late.goals)
    assert torch.equal(plain._generator.get_state(), noisy._generator.get_state())
    assert torch.equal(plain._generator.get_state(), late._generator.get_state())


def test_all_models_reproduce_from_a_seed(rng):
    seed = int(rng.integers(1 << 30))
    kw = dict(device="cpu", seed=seed, actuation=ActuationConfig(latency_range=(0, 40)),
              sensors=SensorConfig(pos_bias_std=0.01, vel_bias_std=0.01, pos_noise_std=1e-3, vel_noise_std=1e-3,
                                   dropout_prob=0.3))
    runs = []
    for env_seed in (seed, seed, seed + 1):
        env = TrajectoryPlanningEnv(32, "B0", **{**kw, "seed": env_seed})
        frames = [env.reset(seed=env_seed)[0]["achieved_goal"]]
        for _ in range(4):
            frames.append(env.step(torch.full((32, 6), 2.0))[0]["observation"].clone())  # fused: the env's buffers
        runs.append((env.sim.latency_cycles.clone(), torch.stack([f[:, :6] for f in frames])))
    assert torch.equal(runs[0][0], runs[1][0]) and torch.equal(runs[0][1], runs[1][1]), rng
    assert not torch.equal(runs[0][1], runs[2][1]), rng


def test_dropout_repeats_the_previous_observation_at_the_asked_rate():
    n, p = 1024, 0.3
    env = TrajectoryPlanningEnv(n, "B0", device="cpu", seed=2,
                                sensors=SensorConfig(pos_noise_std=1e-4, vel_noise_std=1e-4, dropout_prob=p))
    prev, _ = env.reset(seed=2)
    rates = []
    for _ in range(5):
        obs, _, terminated, truncated, info = env.step(torch.full((n, 6), 1.0))
        fresh = terminated | truncated  # an autoreset world shows its new episode's first reading
        same_obs = (obs["observation"] == prev["observation"]).all(1)
        same_pos = (obs["achieved_goal"] == prev["achieved_goal"]).all(1)
        assert torch.equal(same_obs, same_pos), "a dropped reading holds both keys"
        assert not (same_obs & fresh).any()
        fresh_obs = (obs["observation"] != prev["observation"]).all(1)
        assert torch.equal(fresh_obs, ~same_obs), "a reading is either all new (noise) or all held"
        rates.append(same_obs[~fresh].float().mean().item())
        prev = obs
    assert np.mean(rates) == pytest.approx(p, abs=0.03), rates
    again, _ = env.reset()
    assert not (again["achieved_goal"] == prev["achieved_goal"]).all(1).any(), "a reset reading is never dropped"


@pytest.mark.parametrize("build, match", [
    (lambda: ActuationConfig(latency_cycles=-1), "latency_cycles must be >= 0, got -1"),
    (lambda: ActuationConfig(latency_cycles=2.5), "latency_cycles must be an integer >= 0, got 2.5"),
    (lambda: ActuationConfig(latency_range=(5, 2)), r"low <= high, got \(5, 2\)"),
    (lambda: ActuationConfig(latency_range=(0, 3), latency_cycles=1), "not both"),
    (lambda: ActuationConfig(latency_cycles=[1, -2]), r"latency_cycles\[1\] must be >= 0, got -2"),
    (lambda: TrajectoryPlanningEnv(1, "B0", device="cpu", actuation=ActuationConfig(latency_range=(0, 41))),
     r"latency_range=\(0, 41\) exceeds num_cycles=40"),
    (lambda: TrajectoryPlanningEnv(3, "B0", device="cpu", actuation=ActuationConfig(latency_cycles=[1, 2])),
     "one integer or 3 .* got 2 values"),
    (lambda: TrajectoryPlanningEnv(1, "B0", device="cpu", actuation={"latency": 3}), "unknown option.* latency "),
    (lambda: TrajectoryPlanningEnv(1, "B0", device="cpu", sensors=7), "sensors must be a SensorConfig.* got 7"),
    (lambda: SensorConfig(pos_noise_std=-0.1), "pos_noise_std must be >= 0, got -0.1"),
    (lambda: SensorConfig(vel_bias_std=float("nan")), "vel_bias_std must be finite"),
    (lambda: SensorConfig(dropout_prob=1.5), r"dropout_prob must be a probability in \[0, 1\], got 1.5"),
    (lambda: SensorConfig(pos_bias=(0.1, float("inf"))), "pos_bias must be finite"),
    (lambda: TrajectoryPlanningEnv(2, "B0", device="cpu", sensors=SensorConfig(pos_bias=[1.0, 2.0, 3.0])),
     r"pos_bias must broadcast to .* got shape \(3,\)"),
    (lambda: TrajectoryPlanningEnv(1, "B0", device="cpu", std_noise=0.1, sensors=SensorConfig()),
     "std_noise or sensors, not both .*std_noise=0.1"),
])
def test_bad_options_name_the_value(build, match):
    with pytest.raises((ValueError, TypeError), match=match):
        build()


def test_bad_latency_leaves_the_simulator_as_it_was():
    sim = spaced_sim(3, 3, 16)
    sim.set_latency([1, 2, 3])
    for bad, match in (([1, -1, 0], "latency cycles of world 1 must be >= 0, got -1"),
                       ([0, 1.5, 2], "latency cycles of world 1 must be an integer >= 0, got 1.5"),
                       ([1, 2], r"one integer or 3 \(one per world\), got shape \(2,\)"),
                       (-3, "latency cycles must be >= 0, got -3")):
        with pytest.raises(ValueError, match=match):
            sim.set_latency(bad)
    with pytest.raises(ValueError, match=r"latency bound must be at least the largest delay given \(5\), got 4"):
        sim.set_latency(5, bound=4)
    assert sim.latency_cycles.tolist() == [1, 2, 3] and sim.latency_bound == 3
    with pytest.raises(ValueError, match="num_cycles=2 is shorter than the action latency's bound of 3"):
        sim.step(2, torch.ones(3, 3, 2))
    assert not sim.vel.any() and sim.steps_taken == 0, "a refused step does not move"
