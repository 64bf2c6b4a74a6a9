"""Counter-based draws of the sim2real models (magwarp.kernels.sensor_draws): the fill kernels against a plain numpy
reference of the documented layout (Warp's PCG hash), their distributions, and the env-level semantics they carry
(bias per episode, delays over the range, seeds that reproduce, fused step == torch step)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from magwarp.envs.sim2real import SensorConfig, draw_key
from magwarp.envs.trajectory import TrajectoryPlanningEnv
from magwarp.kernels import sensor_draws as kdraw

U32 = np.uint64(0xFFFFFFFF)


def fill_normals(key: int, clock: int, slot: int, num_envs: int, num_movers: int) -> torch.Tensor:
    """``[num_envs, num_movers, 2]`` normals of ``slot`` (the fill kernel, on the CPU)."""
    out = wp.zeros((num_envs, num_movers), dtype=wp.vec2, device="cpu")
    wp.launch(kdraw.fill_normals, dim=(num_envs, num_movers), device="cpu",
              inputs=[wp.array([key], dtype=wp.int32, device="cpu"), wp.int64(clock), slot], outputs=[out])
    return torch.as_tensor(out.numpy())


def pcg(x: np.ndarray) -> np.ndarray:
    """Warp's ``rand_pcg`` on uint32 values (held in uint64 for the wrap-around arithmetic)."""
    x = np.asarray(x, dtype=np.uint64) & U32
    b = (x * np.uint64(747796405) + np.uint64(2891336453)) & U32
    c = (((b >> ((b >> np.uint64(28)) + np.uint64(4))) ^ b) * np.uint64(277803737)) & U32
    return (c >> np.uint64(22)) ^ c


def rand_init(seed, offset) -> np.ndarray:
    return pcg((np.asarray(seed, dtype=np.int64).astype(np.uint64) + pcg(np.asarray(offset, np.int64).astype(
        np.uint64) & U32)) & U32)


def as_int32(x: np.ndarray) -> np.ndarray:
    return (np.asarray(x, dtype=np.uint64) & U32).astype(np.uint32).view(np.int32)


def ref_state(key: int, clock: int, world, slot: int, index) -> np.ndarray:
    """The module docstring's layout."""
    s = rand_init(key, as_int32(np.uint64(np.int64(clock) >> 32 & 0xFFFFFFFF)))
    s = rand_init(as_int32(s), as_int32(np.uint64(np.int64(clock) & 0xFFFFFFFF)))
    s = rand_init(as_int32(s), world)
    return rand_init(as_int32(rand_init(as_int32(s), slot)), index)


def ref_randf(state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    state = pcg(state)
    return state, (state >> np.uint64(8)).astype(np.float32) * np.float32(1.0 / 16777216.0)


CLOCKS = [0, 1, 17, -1, -5, (1 << 33) + 3]


@pytest.mark.parametrize("clock", CLOCKS)
def test_fills_match_the_numpy_reference(clock, rng):
    W, M = 50, 4
    key = int(rng.integers(-(1 << 31), 1 << 31))
    slot = int(rng.integers(0, 9))
    w, m = np.meshgrid(np.arange(W), np.arange(M), indexing="ij")
    state, u1 = ref_randf(ref_state(key, clock, w, slot, m))
    _, u2 = ref_randf(state)
    r = np.sqrt(-2.0 * np.log(1.0 - u1.astype(np.float64)))
    t = 2.0 * np.pi * u2.astype(np.float64)
    ref = np.stack([r * np.cos(t), r * np.sin(t)], -1)
    got = fill_normals(key, clock, slot, W, M).numpy()
    np.testing.assert_allclose(got, ref, rtol=2e-6, atol=2e-6)  # float32 log/sin/cos against float64
    karr = wp.array([key], dtype=wp.int32, device="cpu")
    u = wp.zeros(W, dtype=float, device="cpu")
    wp.launch(kdraw.fill_uniforms, dim=W, inputs=[karr, wp.int64(clock), slot], outputs=[u], device="cpu")
    _, ref_u = ref_randf(ref_state(key, clock, np.arange(W), slot, 0))
    np.testing.assert_array_equal(u.numpy(), ref_u)
    low, span = int(rng.integers(0, 5)), int(rng.integers(1, 41))
    i = wp.zeros(W, dtype=wp.int32, device="cpu")
    wp.launch(kdraw.fill_ints, dim=W, inputs=[karr, wp.int64(clock), slot, low, span], outputs=[i], device="cpu")
    u24 = (ref_u * np.float32(16777216.0)).astype(np.int64)
    np.testing.assert_array_equal(i.numpy(), low + ((u24 * span) >> 24))


def test_normals_uniforms_and_integers_have_their_distributions():
    W, M = 20000, 3
    z = fill_normals(draw_key(3), 5, kdraw.READ, W, M).reshape(-1, 2).double()
    assert abs(z.mean().item()) < 4 / np.sqrt(z.numel())
    assert z.std().item() == pytest.approx(1.0, abs=0.01)
    assert abs(torch.corrcoef(z.T)[0, 1].item()) < 0.02, "x and y of a pair are independent"
    kurt = ((z - z.mean()) ** 4).mean() / z.var() ** 2
    assert kurt.item() == pytest.approx(3.0, abs=0.1)
    other = fill_normals(draw_key(3), 5, kdraw.READ + 1, W, M).reshape(-1).double()
    assert abs(np.corrcoef(z.reshape(-1).numpy(), other.numpy())[0, 1]) < 0.02, "slots are independent"
    nxt = fill_normals(draw_key(3), 6, kdraw.READ, W, M).reshape(-1).double()
    assert abs(np.corrcoef(z.reshape(-1).numpy(), nxt.numpy())[0, 1]) < 0.02, "clocks are independent"
    key = wp.array([draw_key(3)], dtype=wp.int32, device="cpu")
    i = wp.zeros(W, dtype=wp.int32, device="cpu")
    wp.launch(kdraw.fill_ints, dim=W, inputs=[key, wp.int64(5), kdraw.DELAY, 2, 8], outputs=[i], device="cpu")
    counts = np.bincount(i.numpy(), minlength=10)
    assert counts[:2].sum() == 0 and counts.sum() == W
    chi2 = ((counts[2:] - W / 8) ** 2 / (W / 8)).sum()
    assert chi2 < 24.3, counts  # chi-square, 7 degrees of freedom, p = 0.001


def test_env_delays_cover_the_range_uniformly_at_autoresets():
    """Delays drawn inside steps (the fused step's kernel, at autoresets) cover the range uniformly."""
    n = 2048
    env = TrajectoryPlanningEnv(n, "B0", device="cpu", seed=8, max_episode_steps=1, num_cycles=8,
                                actuation={"latency_range": [1, 6]})
    seen = []
    for _ in range(3):  # every world ends its 1-step episode: every step redraws every delay
        env.step(torch.zeros(n, 6))
        seen.append(env.sim.latency_cycles.clone())
    assert not torch.equal(seen[0], seen[1])
    counts = torch.bincount(torch.cat(seen).long(), minlength=8).numpy()
    assert counts[0] == 0 and counts[7] == 0
    expect = 3 * n / 6
    assert ((counts[1:7] - expect) ** 2 / expect).sum() < 20.5, counts  # chi-square, 5 dof, p = 0.001


def test_bias_is_constant_in_an_episode_and_redrawn_at_every_reset():
    n = 256
    env = TrajectoryPlanningEnv(n, "B0", device="cpu", seed=3, max_episode_steps=4,
                                sensors=SensorConfig(pos_bias_std=0.01, vel_bias=0.002, vel_bias_std=0.001))
    env.reset(seed=3)
    biases = [env.sensors.pos_bias.clone()]
    for t in range(8):
        _, _, term, trunc, _ = env.step(torch.zeros(n, 6))
        done = term | trunc
        same = (env.sensors.pos_bias == biases[-1]).all(-1).all(-1)
        assert torch.equal(same, ~done), f"step {t}: only finished worlds redraw"
        biases.append(env.sensors.pos_bias.clone())
    assert (biases[4] != biases[0]).all() and (biases[8] != biases[4]).all()
    env.reset()
    assert (env.sensors.pos_bias != biases[-1]).all(), "reset() outside a step redraws too"


def test_a_reseed_later_reproduces_a_fresh_env():
    """``reset(seed=s)`` after some steps gives the draws of an env built with ``s`` (the draw clock counts from the
    reseed), fused or torch step alike."""
    kw = dict(device="cpu", max_episode_steps=3, actuation={"latency_range": [0, 7]},
              sensors=SensorConfig(pos_bias_std=0.01, pos_noise_std=1e-3, vel_noise_std=1e-3, dropout_prob=0.3))
    fresh = TrajectoryPlanningEnv(32, "B0", seed=12, **kw)
    late = TrajectoryPlanningEnv(32, "B0", seed=1, fused=False, **kw)
    for _ in range(5):
        late.step(torch.ones(32, 6))
    runs = []
    for env in (fresh, late):
        frames = [env.reset(seed=12)[0]["achieved_goal"]]
        for _ in range(6):
            frames.append(env.step(torch.full((32, 6), 2.0))[0]["observation"].clone())  # fused: the env's buffers
        runs.append((torch.stack(frames), env.sim.latency_cycles.clone(), env.sensors.pos_bias.clone()))
    for a, b in zip(*runs):
        assert torch.equal(a, b)
