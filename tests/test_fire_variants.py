"""The reset firing's launch options (magwarp.envs.planar_randomization, benchmarks/fire_cost.py times them): every
block size and thread layout (all of a world's targets in one thread, the CPU's; one or two, the GPU's) draws and writes
the same bits as the default firing: parameters, collision sizes, both margins, body rows and counters, over reset
firings of random masks (none, some, all), interval firings of two periods and competing terms. CPU only (the draws
depend on (key, world, counter, item), not on the device's thread order; a block size is compiled into the CPU module
too, but only CUDA schedules by it: benchmarks/fire_cost.py checks the same bits on CUDA). And the default block size:
64 on CUDA, Warp's on the CPU."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp.envs import planar_randomization as pr
from magwarp.envs.randomization import EventTerm, Gaussian, LogUniform, Uniform
from magwarp.envs.trajectory import TrajectoryPlanningEnv

#: the B0 benchmark's terms (benchmarks/randomization.py PLANAR_TERMS) plus competing, Gaussian, margin and interval ones
CIRCLE_TERMS = [
    EventTerm("mover_mass", LogUniform(0.8, 1.25), op="scale"),
    EventTerm("payload_mass", Uniform(0.0, 0.3), offset=(0.0, 0.01, 0.006), known=True),
    EventTerm("stiffness_lin", Uniform(0.7, 1.3), op="scale"),
    EventTerm("stiffness_rot", Gaussian(1.0, 0.1, clip=(0.7, 1.3)), op="scale"),
    EventTerm("a_max", Uniform(0.9, 1.0), op="scale"),
    EventTerm("v_max", Uniform(0.9, 1.0), op="scale"),
    EventTerm("mover_inertia", Uniform(0.9, 1.1), op="scale"),
    EventTerm("mover_mass", Uniform(2.0, 2.5), targets=(1,)),  # the last one of a field and target sets it
    EventTerm("collision_radius", Uniform(-0.005, 0.0), op="add"),
    EventTerm("collision_margin", Uniform(0.001, 0.002)),
    EventTerm("wall_margin", Gaussian(0.003, 0.0005, clip=(0.002, 0.004))),
    EventTerm("j_max", Uniform(0.9, 1.0), op="scale", mode="interval", interval_steps=2),
    EventTerm("a_max", Uniform(5.0, 6.0), mode="interval", interval_steps=3, targets=(0,)),
    EventTerm("wall_margin", Uniform(0.004, 0.005), mode="interval", interval_steps=3),
]
BOX_TERMS = [
    EventTerm("collision_half_size", Uniform(0.05, 0.06)),
    EventTerm("collision_margin", Uniform(0.001, 0.002)),
    EventTerm("stiffness_lin", Uniform(0.7, 1.3), op="scale", targets=(0, 2)),
    EventTerm("payload_mass", Uniform(0.0, 0.2), targets=(2,)),
]
SIZES_ONLY = [EventTerm("collision_radius", Uniform(-0.005, 0.0), op="add"),
              EventTerm("wall_margin", Uniform(0.0, 0.002), mode="interval", interval_steps=2)]

#: (name, PlanarRandomizer attributes) of each launch option against the default firing (thread layout: one target a
#: thread, the GPU's; the CPU's default block size)
VARIANTS = {
    "block32": {"fire_block": 32},
    "block64": {"fire_block": 64},
    "block128": {"fire_block": 128},
    "two_targets": {"_per_thread": 2},
    "world": {"_per_thread": "world"},  # one thread per world, all its targets (the CPU's layout)
    "world_block64": {"_per_thread": "world", "fire_block": 64},
}

N = 7


def make(terms, per_thread, **kw):
    env = TrajectoryPlanningEnv(N, device="cpu", seed=3, randomization=terms, **kw)
    if per_thread is not None:
        env.randomizer._per_thread = per_thread
    return env


def state(env) -> dict[str, np.ndarray]:
    """Everything a firing writes, as bytes-comparable arrays."""
    sim, r = env.sim, env.randomizer
    out = {"body": sim.model.body.numpy().copy(), "radius": sim.model.radius.numpy().copy(),
           "half_size": sim.model.half_size.numpy().copy(), "margins": sim.model.margins.numpy().copy(),
           "counter": r._counter.numpy().copy()}
    out.update({f"param_{k}": v.numpy().copy() for k, v in sim.mover_params.items()})
    return out


def assert_same(a: dict, b: dict, where: str) -> None:
    assert a.keys() == b.keys()
    for k in a:
        if a[k].dtype.names:  # body rows: field by field (not the struct's padding)
            for f in a[k].dtype.names:
                assert np.ascontiguousarray(a[k][f]).tobytes() == np.ascontiguousarray(b[k][f]).tobytes(), \
                    (where, k, f)
        else:
            assert a[k].tobytes() == b[k].tobytes(), (where, k)


def run(env, masks) -> list[dict]:
    """Reset firings for each mask, an interval firing after each (steps 1..): the state after every firing."""
    r, out = env.randomizer, []
    for mask in masks:
        r.reset(mask)
        out.append(state(env))
        r.step()
        out.append(state(env))
    return out


def masks(seed: int) -> list[torch.Tensor]:
    rng = np.random.default_rng(seed)
    ms = [torch.as_tensor(rng.random(N) < p) for p in (0.3, 0.6, 0.1)]
    return [torch.zeros(N, dtype=torch.bool), *ms, torch.ones(N, dtype=torch.bool), ms[0]]


@pytest.mark.parametrize("terms,kw", [(CIRCLE_TERMS, {}),
                                      (BOX_TERMS, {"collision_shape": "box", "collision_size": (0.06, 0.06)}),
                                      (SIZES_ONLY, {})], ids=["circle", "box", "sizes_only"])
def test_launch_options_give_the_default_firings_bits(terms, kw):
    ref_env = make(terms, 1, **kw)
    assert ref_env.randomizer.fire_block == 0  # the CPU's default
    ref = run(ref_env, masks(0))
    assert any(not np.array_equal(ref[0]["counter"], s["counter"]) for s in ref)  # the firings drew something
    for name, attrs in VARIANTS.items():
        env = make(terms, 1, **kw)
        r = env.randomizer
        for k, v in attrs.items():
            setattr(r, k, r._counter.shape[1] if v == "world" else v)
        got = run(env, masks(0))
        for i, (a, b) in enumerate(zip(ref, got)):
            assert_same(a, b, f"{name} firing {i}")


def test_default_block_size():
    """64 threads a block on CUDA (benchmarks/results/fire_cost_s34_gpu.json), Warp's default (0) on the CPU."""
    assert pr.default_fire_block(True) == 64
    assert pr.default_fire_block(False) == 0
    assert make(SIZES_ONLY, None).randomizer.fire_block == 0
