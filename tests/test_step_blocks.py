"""The fused small-world step with one thread per mover (magwarp.kernels.step_blocks, MAGWARP_SMALL_WORLD_KERNEL=movers)
against the register kernel, bit for bit, on Warp's cooperative CPU blocks (the CUDA shape itself: several worlds a
block, lanes past the last world mirroring it, poses and counts exchanged through shared tiles every cycle): nominal and
randomised body rows, per-world collision sizes, action latency with per-world delays, jerk control,
``stop_on_collision`` on and off, a last block the worlds do not fill, 1, 3 and 8 movers."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from magwarp.kernels import options as kernel_options
from magwarp.kernels import step_blocks
from magwarp.layout import Layout, MoverSpec
from magwarp.sim import Simulator

OUTPUTS = ("pos", "quat", "vel", "omega", "acc", "planar", "flags", "flags_any", "partner", "wall", "world_pairs",
           "world_walls", "halted", "cycles", "pair_list")


def starts(rng, num_worlds: int, num_movers: int) -> np.ndarray:
    """Per-world starts: up to two rows of four movers 0.235 m apart (0.22 m is a collision), jittered, the first
    near the edge of a 6 x 4 tile layout (walls)."""
    k = np.arange(num_movers)
    xy = np.stack([0.13 + 0.235 * (k % 4), 0.36 + 0.235 * (k // 4)], axis=1)
    return xy[None] + rng.uniform(-0.003, 0.003, (num_worlds, num_movers, 2))


def push(rng, sim: Simulator) -> np.ndarray:
    """Commands (unit scale): random, plus a push towards the world's centroid in even worlds (pairs, several at a
    time) and away from the layout's centre in odd ones (walls)."""
    xy = sim.pos[..., :2].numpy().astype(np.float64)
    out = xy - np.array([0.72, 0.48])
    out[::2] = xy[::2].mean(axis=1, keepdims=True) - xy[::2]
    out /= np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-6)
    return out + rng.uniform(-0.7, 0.7, out.shape)


def build(monkeypatch, kernel: str, xy: np.ndarray, block: int, rows: str = "shared", **kw) -> Simulator:
    monkeypatch.setattr(kernel_options, "SMALL_WORLD_KERNEL", kernel)
    monkeypatch.setattr(kernel_options, "SMALL_WORLD_BLOCK", block)
    monkeypatch.setattr(kernel_options, "SMALL_WORLD_ROWS", rows)
    sim = Simulator(Layout.grid(6, 4), num_movers=xy.shape[1], num_worlds=xy.shape[0], device="cpu", start_xy=xy,
                    dt=0.004, **kw)
    assert (sim._movers_block == block) == (kernel == "movers")
    return sim


def randomise(sim: Simulator, rng) -> None:
    """Per-world body rows (mass, inertia, gains, limits, payloads on and off the vertical axis) and radii."""
    p = sim.mover_params
    shape = p["mass"].shape
    for name, lo, hi in (("mass", 0.8, 1.3), ("k_lin", 0.7, 1.3), ("k_rot", 0.7, 1.3), ("inertia", 0.9, 1.1),
                         ("v_max", 0.8, 1.0), ("a_max", 0.8, 1.0), ("j_max", 0.8, 1.0)):
        p[name].mul_(torch.as_tensor(rng.uniform(lo, hi, p[name].shape), dtype=p[name].dtype))
    p["payload"].copy_(torch.as_tensor(rng.uniform(0.0, 0.5, shape)))
    off = torch.as_tensor(rng.uniform(-0.01, 0.01, (*shape, 3)))
    off[..., 2] = 0.01
    off[: shape[0] // 2, :, :2] = 0.0  # on the vertical axis in half the worlds
    p["payload_offset"].copy_(off)
    sim.commit_mover_params()
    sim.make_per_world("radius", "half_size")
    sim.model.radius.assign(rng.uniform(0.1, 0.112, (sim.num_worlds, sim.num_movers)).astype(np.float32))
    sim.model.half_size.assign(rng.uniform(0.07, 0.08, (sim.num_worlds, sim.num_movers, 2)).astype(np.float32))


def outputs(sim: Simulator) -> dict[str, bytes]:
    return {name: getattr(sim.state, name).numpy().tobytes() for name in OUTPUTS}


CASES = {  # num_movers, num_worlds, block, options
    "m3-nominal": (3, 23, 24, {}),
    "m3-random-latency-box": (3, 23, 32, {"random": True, "latency": True, "mover": MoverSpec(collision_shape="box")}),
    "m3-jerk-no-stop": (3, 10, 24, {"control": "jerk", "stop_on_collision": False}),
    "m3-random-no-stop-latency-rows-in-registers": (3, 9, 16, {"random": True, "latency": True, "rows": "registers",
                                                                "stop_on_collision": False}),
    "m1-latency": (1, 11, 8, {"latency": True}),
    "m8-random": (8, 7, 24, {"random": True}),
    "m8-random-rows-in-registers": (8, 5, 16, {"random": True, "rows": "registers"}),
    "m8-no-stop-jerk-box": (8, 3, 16, {"control": "jerk", "stop_on_collision": False,
                                       "mover": MoverSpec(collision_shape="box")}),
}


def both(monkeypatch, xy: np.ndarray, block: int, random_seed: int | None = None, delays=None, **opts):
    """A simulator with the register kernel and one with the movers kernel, set up alike (the knob is read at every
    kernel build: each sim is set up under its own)."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    sims = []
    for kernel in ("registers", "movers"):
        sim = build(monkeypatch, kernel, xy, block, **opts)
        if random_seed is not None:
            randomise(sim, np.random.default_rng(random_seed))
        if delays is not None:
            sim.set_latency(delays, bound=6)
        assert sim._movers_block == (block if kernel == "movers" else 0)
        sims.append(sim)
    return sims


def step_both(sims, cmd, num_cycles: int, rng) -> None:
    for sim in sims:
        sim.step(num_cycles, cmd)
    want, got = outputs(sims[0]), outputs(sims[1])
    for name in OUTPUTS:
        assert got[name] == want[name], f"{name} differs ({rng})"


@pytest.mark.parametrize("case", list(CASES))
def test_movers_kernel_equals_the_register_kernel_bit_for_bit(rng, monkeypatch, case):
    num_movers, num_worlds, block, opts = CASES[case]
    opts = dict(opts)
    random, latency = opts.pop("random", False), opts.pop("latency", False)
    jerk = opts.get("control") == "jerk"
    delays = torch.as_tensor(rng.integers(0, 7, num_worlds), dtype=torch.int32) if latency else None
    sims = both(monkeypatch, starts(rng, num_worlds, num_movers), block,
                int(rng.integers(2**31)) if random else None, delays, **opts)
    pairs = walls = multi = halted_early = 0
    for _ in range(6):
        step_both(sims, torch.as_tensor(push(rng, sims[0]) * (400.0 if jerk else 14.0), dtype=torch.float32), 10, rng)
        s = sims[0].state
        pairs += int((s.world_pairs.numpy() > 0).sum())
        walls += int((s.world_walls.numpy() > 0).sum())
        halted_early += int((s.cycles.numpy() < 10).sum())
        pl, n = s.pair_list.numpy(), s.world_pairs.numpy()  # movers in two pairs: the partner is the lowest index
        multi += sum(int((np.bincount(pl[w, :n[w]].ravel(), minlength=num_movers) > 1).sum())
                     for w in range(num_worlds))
    print(case, "worlds with pairs", pairs, "movers in several pairs", multi, "worlds with walls", walls,
          "halted early", halted_early)
    assert (pairs > 0 or num_movers == 1) and walls > 0, "the case must exercise pairs and walls"
    assert multi > 0 or num_movers < 3 or opts.get("stop_on_collision", True), "a mover in several pairs"
    if opts.get("stop_on_collision", True):
        assert halted_early > 0, "stop_on_collision must stop some world before the step's last cycle"


@pytest.mark.parametrize("stop", [False, True])
def test_flags_accumulate_over_the_step(rng, monkeypatch, stop):
    # Two movers start overlapping (0.212 m apart, 0.22 m collides) and are driven apart: they collide in the first
    # cycles only. Without stop_on_collision, flags_any keeps the collision that the last cycle's flags no longer show.
    xy = np.array([[[0.5, 0.5], [0.712, 0.5]]] * 3) + rng.uniform(-0.001, 0.001, (3, 2, 2))
    sims = both(monkeypatch, xy, 8, stop_on_collision=stop, validate_starts=False)
    step_both(sims, torch.tensor([[[-10.0, 0.0], [10.0, 0.0]]] * 3), 12, rng)
    s = sims[0].state
    assert (s.flags_any.numpy() != 0).all() and (s.halted.numpy() == 1).all()
    if stop:
        assert (s.cycles.numpy() == 1).all() and (s.flags.numpy() != 0).all()
    else:
        assert (s.cycles.numpy() == 12).all() and (s.flags.numpy() == 0).all() and (s.world_pairs.numpy() == 0).all()


def test_blocks_and_fallbacks(monkeypatch):
    assert step_blocks.worlds_per_block(3, 96) == 32 and step_blocks.num_blocks(65536, 3, 96) == 2048
    assert step_blocks.num_blocks(23, 3, 24) == 3 and step_blocks.worlds_per_block(8, 8) == 1
    with pytest.raises(ValueError, match="block of 4 threads cannot hold a world of 8 movers"):
        step_blocks.worlds_per_block(8, 4)
    with pytest.raises(ValueError, match="1 to 31 movers, got 32"):
        step_blocks.make_movers_kernel(None, 32)
    with pytest.raises(ValueError, match="rows must be 'registers' or 'shared', got 'global'"):
        step_blocks.make_movers_kernel(None, 3, rows="global")
    xy = np.array([[[0.13, 0.36], [0.37, 0.36]]])
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", False)  # no cooperative CPU blocks: the register kernel
    sim = build(monkeypatch, "registers", xy, 96)
    monkeypatch.setattr(kernel_options, "SMALL_WORLD_KERNEL", "movers")
    sim._build_kernels()
    assert sim._movers_block == 0
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    sim._build_kernels()
    assert sim._movers_block == 96 and sim._fused_kernel is sim._movers_kernel
    sim._actuator = object()  # what set_actuator leaves: the register kernel
    assert sim._small_world_block() == 0
    sim._actuator = None
    assert sim._small_world_block() == 96
    monkeypatch.setattr(kernel_options, "SMALL_WORLD_BLOCK", 1)  # a world of 2 movers needs 2 threads
    assert sim._small_world_block() == 0


def test_trajectory_env_fused_step_with_the_movers_kernel(monkeypatch):
    # The trajectory env's fused step (its graphs keyed on the simulator's kernels) with full randomisation, latency
    # drawn at resets and autoresets: the same observations, rewards and flags with either small-world kernel.
    from magwarp.envs.trajectory import TrajectoryPlanningEnv

    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    monkeypatch.setattr(kernel_options, "SMALL_WORLD_BLOCK", 32)
    runs = []
    for kernel in ("registers", "movers"):
        monkeypatch.setattr(kernel_options, "SMALL_WORLD_KERNEL", kernel)
        env = TrajectoryPlanningEnv(12, device="cpu", seed=5, randomization="sim2real", max_episode_steps=6,
                                    actuation={"latency_range": [0, 5]})
        env.reset(seed=5)
        assert env.step_path == "fused" and env.sim._movers_block == (32 if kernel == "movers" else 0)
        gen = torch.Generator().manual_seed(6)
        out = []
        for _ in range(8):
            obs, reward, terminated, truncated, _ = env.step(torch.rand((12, *env.single_action_space.shape),
                                                                        generator=gen) * 2 - 1)
            out.append([t.clone() for t in (*obs.values(), reward, terminated, truncated)])
        runs.append(out)
    assert any(bool(step[-1].any() or step[-2].any()) for step in runs[0]), "autoresets must happen"
    for a, b in zip(*runs):
        for x, y in zip(a, b):
            assert torch.equal(x, y)
