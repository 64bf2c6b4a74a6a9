"""#24's fire-cost candidates (magwarp.envs.planar_randomization's ``fire*`` options, magwarp.kernels.randomize): every
layout, body and launch option draws and writes the same bits as the default firing (fire_terms over the grid):
parameters, collision sizes, both margins, body rows and counters, over reset firings of random masks (none, some,
all), interval firings of two periods and competing terms, each thread layout (all of a world's targets in one thread,
the CPU's; one or two, the GPU's). CPU only (the draws depend on (key, world, counter, item), not on the device's
thread order; benchmarks/fire_cost.py checks the same on CUDA)."""

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

#: (name, PlanarRandomizer attributes) of each candidate
VARIANTS = {
    "grid_lean": {"fire_lean": True},
    "grid_block32": {"fire_block": 32},
    "grid_capped": {"fire_max_registers": 64},  # (the cap is CUDA's: on the CPU, fire_terms_capped's code path)
    "compact": {"fire": "compact"},
    "compact_lean": {"fire": "compact", "fire_lean": True},
    "compact_stride": {"fire": "compact", "fire_grid_worlds": 2},  # a grid of 2 worlds: the grid-stride loop
    "compact_lean_stride": {"fire": "compact", "fire_lean": True, "fire_grid_worlds": 3},
    "split": {"fire": "split"},
    "split_stride": {"fire": "split", "fire_grid_worlds": 2},
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


@pytest.mark.parametrize("per_thread", [None, 1, 2])  # None: the CPU's (a world's 3 targets in one thread)
@pytest.mark.parametrize("terms,kw", [(CIRCLE_TERMS, {}),
                                      (BOX_TERMS, {"collision_shape": "box", "collision_size": (0.06, 0.06)}),
                                      (SIZES_ONLY, {})], ids=["circle", "box", "sizes_only"])
def test_variants_give_the_default_firings_bits(terms, kw, per_thread):
    ref_env = make(terms, per_thread, **kw)
    assert ref_env.randomizer.fire == "grid" and not ref_env.randomizer.fire_lean  # today's default
    ref = run(ref_env, masks(per_thread or 0))
    assert any(not np.array_equal(ref[0]["counter"], s["counter"]) for s in ref)  # the firings drew something
    for name, attrs in VARIANTS.items():
        env = make(terms, per_thread, **kw)
        for k, v in attrs.items():
            setattr(env.randomizer, k, v)
        got = run(env, masks(per_thread or 0))
        for i, (a, b) in enumerate(zip(ref, got)):
            assert_same(a, b, f"{name} firing {i}")


def test_compact_lists_exactly_the_masked_worlds():
    """list_worlds: the masked worlds, each once (in some order), and their count; zeroed again by each firing."""
    env = make(CIRCLE_TERMS, 1)
    r = env.randomizer
    r.fire = "compact"
    for mask in masks(7):
        r.reset(mask)
        n = int(r._list_count.numpy()[0])
        assert n == int(mask.sum())
        assert sorted(r._list_ids.numpy()[:n].tolist()) == torch.nonzero(mask).flatten().tolist()


def test_unknown_layout_is_refused():
    env = make(CIRCLE_TERMS, None)
    env.randomizer.fire = "sparse"
    with pytest.raises(ValueError, match="fire must be one of"):
        env.randomizer.reset(torch.ones(N, dtype=torch.bool))
    env.randomizer.step()  # an all-worlds firing takes the grid whatever the layout (interval: step 1, nothing due)


def test_module_defaults_are_todays():
    """The defaults a new randomizer takes: today's firing (the one-line switch to a candidate is these constants)."""
    assert (pr.FIRE, pr.FIRE_LEAN, pr.FIRE_BLOCK, pr.FIRE_MAX_REGISTERS, pr.FIRE_GRID_WORLDS) == ("grid", False, None,
                                                                                                  0, 0)


def test_default_block_size():
    """64 threads a block on CUDA (benchmarks/results/fire_cost_s34_gpu.json), Warp's default (0) on the CPU."""
    assert pr.default_fire_block(True) == 64
    assert pr.default_fire_block(False) == 0
    assert make(SIZES_ONLY, None).randomizer.fire_block == 0
