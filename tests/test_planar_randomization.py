"""Domain randomisation on the planar simulator (magwarp.envs.planar_randomization) through the trajectory env:
per-world parameters in the step kernels (defaults pack to the constructor's bits), distributions (moments over many
worlds), only the targeted worlds change, seeds reproduce, F = m a where mass enters the planar model (the x/y drive,
the z hold, a payload's gravity torque), per-world limits clip, per-world collision margins, presets."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from magwarp.envs.randomization import PRESETS, EventTerm, Gaussian, LogUniform, Uniform
from magwarp.envs.trajectory import TrajectoryPlanningEnv
from magwarp.kernels import options as kernel_options
from magwarp.layout import Layout
from magwarp.sim import Simulator

from conftest import cuda_available

DT = 1e-3
MASS = 1.24  # MoverSpec's default


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Body rows equal bit for bit, field by field (the struct's padding bytes are not compared)."""
    return all(np.ascontiguousarray(a[f]).tobytes() == np.ascontiguousarray(b[f]).tobytes() for f in a.dtype.names)


def make(n=8, terms=None, seed=0, **kw):
    return TrajectoryPlanningEnv(n, device="cpu", seed=seed, randomization=terms, **kw)


def test_default_parameters_pack_to_the_constructors_bits():
    sim = Simulator(Layout.grid(4, 3), num_movers=3, num_worlds=4, device="cpu", stiffness_lin=(1.0, 1.0, 37.0),
                    stiffness_rot=(0.3, 0.2, 0.7), v_max=1.7, a_max=9.3, j_max=77.0)
    before = sim.model.body.numpy().copy()
    assert before.shape == (1, 3)  # one row shared by all worlds until randomisation asks for more
    sim.commit_mover_params()
    after = sim.model.body.numpy()
    assert after.shape == (4, 3)
    assert all(np.array_equal(np.repeat(before[f], 4, 0), after[f]) for f in before.dtype.names)
    assert after["drive_gain"].min() == after["drive_gain"].max() == 1.0


@pytest.mark.parametrize("num_movers, control", [(3, "acceleration"), (3, "jerk"), (40, "acceleration")],
                         ids=["registers", "registers-jerk", "many-movers"])
def test_nominal_kernels_equal_the_general_ones_bit_for_bit(rng, num_movers, control):
    # The simulator compiles the body rows as built (drive gain 1, no payload, the shared gains) until a row can
    # differ; committing the configured parameters switches to the general kernels, which must give the same bits.
    def build():
        return Simulator(Layout.grid(8, 8), num_movers=num_movers, num_worlds=3, device="cpu", control=control,
                         stiffness_lin=(1.0, 1.0, 37.0), stiffness_rot=(0.3, 0.2, 0.7), stop_on_collision=False)

    nominal, general = build(), build()
    general.commit_mover_params()
    assert nominal._fused_kernel is not general._fused_kernel  # the two compiled variants
    for _ in range(4):
        cmd = torch.as_tensor(rng.uniform(-12.0, 12.0, (3, num_movers, 2)), dtype=torch.float32)
        nominal.step(10, cmd)
        general.step(10, cmd)
        for name in ("pos", "quat", "vel", "omega", "acc"):
            assert torch.equal(getattr(nominal, name), getattr(general, name)), name


@pytest.mark.parametrize("rows", [r for r in kernel_options.REGISTER_ROWS_CHOICES if r != kernel_options.REGISTER_ROWS])
def test_register_row_variants_equal_bit_for_bit(monkeypatch, rows):
    # MAGWARP_REGISTER_ROWS (a benchmark knob) picks which per-world rows the general register kernel holds in
    # registers; every variant steps a randomised world with latency to the same bits as the default.
    def run():
        env = make(6, "sim2real", seed=3, actuation={"latency_range": [0, 5]})
        env.reset(seed=3)
        gen = torch.Generator().manual_seed(4)
        for _ in range(5):
            env.step(torch.rand((6, *env.single_action_space.shape), generator=gen) * 2 - 1)
        return env.sim

    default = run()
    monkeypatch.setattr(kernel_options, "REGISTER_ROWS", rows)
    variant = run()
    assert variant._fused_kernel is not default._fused_kernel  # another compiled variant
    for name in ("pos", "quat", "vel", "omega", "acc"):
        assert torch.equal(getattr(default, name), getattr(variant, name)), name


def test_terms_draw_from_their_distributions():
    n = 1200
    env = make(n, [EventTerm("mover_mass", Uniform(1.0, 1.6)),
                   EventTerm("stiffness_lin", LogUniform(0.5, 2.0), op="scale"),
                   EventTerm("a_max", Gaussian(9.0, 0.4, clip=(7.0, 11.0))),
                   EventTerm("collision_radius", Uniform(-0.01, 0.0), op="add")])
    body = env.sim.model.body.numpy()
    k = n * 3
    mass = body["mass"].reshape(-1).astype(np.float64)
    assert abs(mass.mean() - 1.3) < 4 * 0.6 / math.sqrt(12 * k)
    assert abs(mass.var() - 0.36 / 12) < 0.15 * 0.36 / 12
    assert mass.min() >= 1.0 and mass.max() <= 1.6
    ratio = np.log(body["k_lin"][..., 2].reshape(-1) / 100.0)  # log of a log-uniform scale: uniform on [-ln2, ln2]
    assert abs(ratio.mean()) < 4 * (2 * math.log(2)) / math.sqrt(12 * 3 * k)
    assert abs(ratio.var() - (2 * math.log(2)) ** 2 / 12) < 0.1 * (2 * math.log(2)) ** 2 / 12
    a = body["a_max"].reshape(-1)
    assert abs(a.mean() - 9.0) < 4 * 0.4 / math.sqrt(k) and abs(a.std() - 0.4) < 0.05
    r = env.sim.radii.numpy().reshape(-1) - 0.11
    assert abs(r.mean() + 0.005) < 4 * 0.01 / math.sqrt(12 * k) and r.min() >= -0.01 - 1e-7 and r.max() <= 1e-7
    # packed consistently: inverse mass, drive gain m_ctrl / m, damping from the controller's mass
    np.testing.assert_allclose(body["inv_mass"], 1.0 / body["mass"], rtol=1e-6)
    np.testing.assert_allclose(body["drive_gain"], MASS / body["mass"], rtol=1e-6)
    np.testing.assert_allclose(body["damp_lin"], 2 * np.sqrt(body["k_lin"] * MASS), rtol=1e-6)
    # independent across components and movers (each its own generator state): no correlation beyond chance
    bound = 4 / math.sqrt(n)
    for x in (np.log(body["k_lin"].reshape(-1, 3).astype(np.float64)), mass.reshape(n, 3), a):
        c = np.corrcoef(x.reshape(-1, 3).T)
        assert np.abs(c[np.triu_indices(3, 1)]).max() < bound


def test_only_the_targeted_worlds_and_movers_change():
    env = make(6, [EventTerm("mover_mass", Uniform(2.0, 3.0), targets=(1,)),
                   EventTerm("collision_margin", Uniform(0.0, 0.002)),
                   EventTerm("v_max", Uniform(1.0, 1.5), mode="startup")])
    body0, margins0 = env.sim.model.body.numpy().copy(), env.sim.margins.clone()
    assert np.all(body0["mass"][:, [0, 2]] == np.float32(MASS)) and np.all(body0["mass"][:, 1] >= 2.0)
    mask = torch.tensor([True, False, False, True, False, False])
    env.reset(options={"reset_mask": mask})
    body1 = env.sim.model.body.numpy()
    keep = ~mask.numpy()
    assert same(body1[keep], body0[keep])
    assert torch.equal(env.sim.margins[~mask], margins0[~mask])
    assert np.all(body1["mass"][mask.numpy(), 1] != body0["mass"][mask.numpy(), 1])
    assert np.all(body1["mass"][:, [0, 2]] == np.float32(MASS))
    assert np.array_equal(body1["v_max"], body0["v_max"])  # startup terms never fire again


def test_seeds_reproduce():
    terms = [EventTerm("mover_mass", LogUniform(0.8, 1.25), op="scale"),
             EventTerm("payload_mass", Uniform(0.0, 0.3), offset=(0.02, 0.0, 0.01)),
             EventTerm("stiffness_rot", Uniform(0.7, 1.3), op="scale")]
    a, b = make(16, terms, seed=3), make(16, terms, seed=3)
    assert same(a.sim.model.body.numpy(), b.sim.model.body.numpy())
    assert not np.array_equal(make(16, terms, seed=4).sim.model.body.numpy()["mass"], a.sim.model.body.numpy()["mass"])
    for _ in range(5):  # a history of steps and autoresets, then the same reseed: the same draws
        b.step(torch.full((16, 6), 9.0))
    a.reset(seed=11)
    b.reset(seed=11)
    assert same(a.sim.model.body.numpy(), b.sim.model.body.numpy())


def _one_cycle(env, cmd):
    """One control cycle from rest with command ``cmd`` [W, M, 2]."""
    env.sim.reset()
    env.sim.step(1, cmd)


def test_heavier_mover_accelerates_as_f_equals_m_a():
    """The controller drives with its own mass: F = m_ctrl a_cmd = m a, so a = a_cmd m_ctrl / m in x/y."""
    masses = [MASS, 2 * MASS, 0.5 * MASS, 3.1]
    env = make(4, [EventTerm("mover_mass", Uniform(1.0, 1.0), op="scale", mode="startup")])
    p = env.sim.mover_params
    p["mass"].copy_(torch.tensor(masses, dtype=torch.float64)[:, None].expand(4, 3))
    env.sim.commit_mover_params()
    cmd = torch.zeros(4, 3, 2)
    cmd[..., 0] = 4.0
    _one_cycle(env, cmd)
    expect = 4.0 * MASS / np.array(masses) * DT
    np.testing.assert_allclose(env.sim.vel[:, :, 0].numpy(), expect[:, None].repeat(3, 1), rtol=1e-5)
    assert torch.all(env.sim.acc[..., 0] == 4.0)  # the carried (commanded) acceleration state
    # z: the hold's force on a displaced target accelerates the true mass, K dz / m (at rest: no damping yet)
    env.sim.reset()
    tgt = env.sim.state.target_pos
    env.sim._t(tgt)[..., 2] += 0.001
    env.sim.step(1, torch.zeros(4, 3, 2))
    vz = env.sim.vel[:, 0, 2].numpy()
    np.testing.assert_allclose(vz, 100.0 * 0.001 / np.array(masses) * DT, rtol=1e-4)
    # levitation carries the true weight: no sag at rest
    env.sim.reset()
    env.sim.step(40, torch.zeros(4, 3, 2))
    np.testing.assert_allclose(env.sim.pos[..., 2].numpy(), 0.01, atol=1e-6)


def test_known_payload_keeps_commanded_motion_unknown_lags():
    """A payload the controller is configured for (known=True): F = (m_ctrl + p) a_cmd = (m + p) a, the x/y motion is
    as commanded; an unknown one lags, a = a_cmd m_ctrl / (m + p). Only the payload's worlds (reset mask) change."""
    p = 0.31
    for known, gain in ((True, 1.0), (False, MASS / (MASS + p))):
        env = make(4, [EventTerm("payload_mass", Uniform(p, p), known=known)])
        env.reset(seed=1)
        mask = torch.tensor([True, False, True, False])
        params = env.sim.mover_params
        params["payload"].zero_()
        params["payload_known"].zero_()
        env.sim.commit_mover_params()
        env.randomizer.reset(mask)
        np.testing.assert_array_equal(params["payload_known"][:, 0].numpy(), [p * known, 0, p * known, 0])
        cmd = torch.zeros(4, 3, 2)
        cmd[..., 1] = 5.0
        _one_cycle(env, cmd)
        expect = np.where(mask.numpy(), 5.0 * gain * DT, 5.0 * DT)
        np.testing.assert_allclose(env.sim.vel[:, :, 1].numpy(), expect[:, None].repeat(3, 1), rtol=1e-5)
        body = env.sim.model.body.numpy()
        m_c = MASS + p * known
        np.testing.assert_allclose(body["damp_lin"][0, :, 2], 2 * np.sqrt(100.0 * m_c), rtol=1e-6)
        np.testing.assert_allclose(body["mass"][0], MASS + p, rtol=1e-6)


def test_payload_offset_gravity_torque():
    """A payload off centre: gravity's torque about the centre (the levitation carries the weight there) over the
    parallel-axis inertia, in the first cycle from rest."""
    env = make(2, [EventTerm("payload_mass", Uniform(0.4, 0.4), offset=(0.03, 0.0, 0.0), targets=(0,),
                             mode="startup")])
    _one_cycle(env, torch.zeros(2, 3, 2))
    m, p, r = MASS, 0.4, 0.03
    total = m + p
    com_x = p / total * r
    inertia_y = env.sim.mover.inertia[1] + m * p / total * r * r
    alpha = com_x * total * 9.81 / inertia_y  # (r x (0, 0, -M g))_y = x M g: the loaded +x side dips
    np.testing.assert_allclose(env.sim.omega[:, 0, 1].numpy(), alpha * DT, rtol=1e-4)
    assert torch.all(env.sim.omega[:, 1:] == 0)


@pytest.mark.parametrize("jerk", [False, True])
def test_limits_clip_per_world(jerk):
    env = make(3, [EventTerm("a_max", Uniform(1.0, 1.0), mode="startup"),
                   EventTerm("j_max", Uniform(1.0, 1.0), mode="startup"),
                   EventTerm("v_max", Uniform(1.0, 1.0), mode="startup")], learn_jerk=jerk)
    p = env.sim.mover_params
    p["a_max"].copy_(torch.tensor([2.0, 5.0, 8.0], dtype=torch.float64)[:, None].expand(3, 3))
    p["j_max"].copy_(torch.tensor([20.0, 50.0, 80.0], dtype=torch.float64)[:, None].expand(3, 3))
    p["v_max"].copy_(torch.tensor([0.02, 0.05, 0.5], dtype=torch.float64)[:, None].expand(3, 3))
    env.sim.commit_mover_params()
    cmd = torch.zeros(3, 3, 2)
    cmd[..., 1] = 1000.0
    _one_cycle(env, cmd)
    first = env.sim.acc[:, 0, 1].numpy()
    np.testing.assert_allclose(first, ([20.0, 50.0, 80.0] if jerk else [2.0, 5.0, 8.0]) * np.array([DT if jerk else 1]),
                               rtol=1e-5)
    env.sim.step(200, cmd)
    speed = env.sim.vel[:, 0, :2].norm(dim=-1).numpy()
    np.testing.assert_allclose(speed, [0.02, 0.05, 0.5], rtol=1e-5)


def test_collision_margin_per_world():
    env = make(2, [EventTerm("collision_margin", Uniform(0.0, 0.0), mode="startup")], collision_size=0.05)
    env.sim.margins[1, 0] = 0.02  # world 1: a 2 cm safety margin on each mover
    start = [[0.12, 0.3], [0.25, 0.3], [0.7, 0.4]]  # 0.13 m apart: free, unless 2 (0.05 + 0.02) > 0.13
    env.sim.start_pos[..., :2] = torch.tensor(start)
    env.sim.reset()
    env.sim.check_collisions()
    assert env.sim.flags.numpy()[:, :2].tolist() == [[0, 0], [1, 1]]


def test_interval_terms_fire_every_n_steps():
    env = make(2, [EventTerm("a_max", Uniform(5.0, 9.0), mode="interval", interval_steps=3)])
    seen = []
    for _ in range(7):
        seen.append(env.sim.model.body.numpy()["a_max"].copy())
        env.step(torch.zeros(2, 6))
    changed = [not np.array_equal(seen[i], seen[i + 1]) for i in range(6)]
    assert changed == [False, False, True, False, False, True]


def test_last_due_term_wins_per_field_and_mover():
    """Two terms of one field and mover: the later one in the table sets it (a payload term also its offset and
    known); of two interval terms, the later one wins only at the steps where it is due."""
    terms = [EventTerm("mover_mass", Uniform(2.0, 2.5)),
             EventTerm("mover_mass", Uniform(5.0, 5.5), targets=(1,)),
             EventTerm("payload_mass", Uniform(0.1, 0.2), offset=(0.01, 0.0, 0.0), known=True),
             EventTerm("payload_mass", Uniform(0.3, 0.4), offset=(0.0, 0.0, 0.005), targets=(2,)),
             EventTerm("a_max", Uniform(1.0, 2.0), mode="interval", interval_steps=2),
             EventTerm("a_max", Uniform(5.0, 6.0), mode="interval", interval_steps=3, targets=(0,))]
    env = make(5, terms)
    p, r = env.sim.mover_params, env.randomizer

    def within(x, lo, hi):
        x = np.asarray(x)
        return bool(((x >= lo) & (x <= hi)).all())

    mass, pay = p["mass"].numpy(), p["payload"].numpy()
    assert within(mass[:, [0, 2]], 2.0, 2.5) and within(mass[:, 1], 5.0, 5.5)
    assert within(pay[:, :2], 0.1, 0.2) and within(pay[:, 2], 0.3, 0.4)
    np.testing.assert_array_equal(p["payload_offset"][:, :2].numpy(), np.broadcast_to([0.01, 0.0, 0.0], (5, 2, 3)))
    np.testing.assert_array_equal(p["payload_offset"][:, 2].numpy(), np.broadcast_to([0.0, 0.0, 0.005], (5, 3)))
    np.testing.assert_array_equal(p["payload_known"].numpy(), np.where([True, True, False], pay, 0.0))
    np.testing.assert_allclose(env.sim.model.body.numpy()["mass"], mass + pay, rtol=1e-6)  # packed after the draws
    counter = r._counter.clone()
    previous = p["a_max"].clone()
    for step in range(1, 7):
        r.step()
        a = p["a_max"].numpy()
        two, three = step % 2 == 0, step % 3 == 0
        if three:
            assert within(a[:, 0], 5.0, 6.0), step
        elif two:
            assert within(a[:, 0], 1.0, 2.0), step
        if two:
            assert within(a[:, 1:], 1.0, 2.0) and np.all(a[:, 1:] != previous[:, 1:].numpy()), step
        else:
            assert torch.equal(p["a_max"][:, 1:], previous[:, 1:]), step
        assert torch.equal(p["a_max"], previous) == (not (two or three)), step
        previous = p["a_max"].clone()
    assert torch.equal(r._counter, counter + 4)  # one per firing (steps 2, 3, 4 and 6), whatever fired in it


def test_worlds_not_drawn_keep_rows_and_counters_bit_for_bit():
    """A reset firing for some worlds: the others keep every row (body, box sizes, both margins, the parameters)
    bit for bit and their counters; the drawn ones advance theirs by one and get every component drawn."""
    terms = [EventTerm("collision_half_size", Uniform(0.05, 0.06)),
             EventTerm("collision_margin", Uniform(0.001, 0.002)),
             EventTerm("wall_margin", Uniform(0.003, 0.004)),
             EventTerm("stiffness_lin", Uniform(0.7, 1.3), op="scale", targets=(0, 2))]
    env = make(6, terms, collision_shape="box", collision_size=(0.06, 0.06))
    sim, r = env.sim, env.randomizer
    before = {"body": sim.model.body.numpy().copy(), "half": sim.half_sizes.clone(), "margins": sim.margins.clone(),
              "counter": r._counter.clone(), **{k: v.clone() for k, v in sim.mover_params.items()}}
    mask = torch.tensor([True, False, False, True, False, True])
    r.reset(mask)
    keep = ~mask
    assert same(sim.model.body.numpy()[keep.numpy()], before["body"][keep.numpy()])
    for name, now in (("half", sim.half_sizes), ("margins", sim.margins), ("counter", r._counter),
                      *sim.mover_params.items()):
        assert torch.equal(now[keep], before[name][keep]), name
    assert torch.equal(r._counter[mask], before["counter"][mask] + 1)
    half, margins = sim.half_sizes[mask].numpy(), sim.margins[mask].numpy()
    assert half.min() >= np.float32(0.05) and half.max() <= np.float32(0.06) and np.all(half[..., 0] != half[..., 1])
    assert np.all((margins[:, 0] >= np.float32(0.001)) & (margins[:, 0] <= np.float32(0.002)))
    assert np.all((margins[:, 1] >= np.float32(0.003)) & (margins[:, 1] <= np.float32(0.004)))
    k_lin = sim.mover_params["k_lin"]
    assert torch.equal(k_lin[:, 1], before["k_lin"][:, 1])
    assert torch.all(k_lin[mask][:, [0, 2]] != before["k_lin"][mask][:, [0, 2]])


@pytest.mark.parametrize("per_thread", [1, 2])
def test_draws_do_not_depend_on_other_worlds_or_the_thread_layout(per_thread):
    """Each world, mover and component draws from its own generator state: a world gets the same values whichever
    other worlds are drawn for in the same firing, and whichever targets share a thread (the GPU's layout: one per
    thread; the CPU's: all of a world's)."""
    terms = [EventTerm("mover_mass", LogUniform(0.8, 1.25), op="scale"),
             EventTerm("stiffness_rot", Gaussian(1.0, 0.1, clip=(0.7, 1.3)), op="scale"),
             EventTerm("payload_mass", Uniform(0.0, 0.2), targets=(0, 2)),
             EventTerm("wall_margin", Uniform(0.0, 0.002))]
    a, b, c = (make(6, terms, seed=5) for _ in range(3))
    assert a.randomizer._per_thread == 3  # the CPU's
    c.randomizer._per_thread = per_thread
    everyone = torch.ones(6, dtype=torch.bool)
    a.randomizer.reset(everyone)
    c.randomizer.reset(everyone)
    b.randomizer.reset(torch.tensor([False, True, False, False, True, False]))
    assert same(a.sim.model.body.numpy(), c.sim.model.body.numpy())
    assert torch.equal(a.randomizer._counter, c.randomizer._counter) and torch.equal(a.sim.margins, c.sim.margins)
    for w in (1, 4):
        assert same(a.sim.model.body.numpy()[w], b.sim.model.body.numpy()[w]), w
        for key in ("mass", "k_rot", "payload"):
            assert torch.equal(a.sim.mover_params[key][w], b.sim.mover_params[key][w]), (w, key)
        assert torch.equal(a.sim.margins[w], b.sim.margins[w])


def test_preset_and_mappings_from_json():
    env = make(4, "sim2real")
    assert {t.field for t in env.randomizer.terms} >= {"mover_mass", "payload_mass", "stiffness_lin", "a_max"}
    env2 = make(4, [{"field": "v_max", "dist": {"uniform": [1.0, 1.5]}}])
    assert env2.sim.model.body.numpy()["v_max"].max() <= 1.5


def test_bad_terms_are_named():
    with pytest.raises(ValueError, match="'object_mass' is not one of this env's"):
        make(2, [EventTerm("object_mass", Uniform(0.2, 0.4))])
    with pytest.raises(ValueError, match="unstable at dt"):
        make(2, [EventTerm("stiffness_lin", Uniform(1.0, 2e6))])
    with pytest.raises(ValueError, match="preset 'nope' is unknown"):
        make(2, "nope")
    with pytest.raises(ValueError, match="'collision_half_size'.*none"):
        make(2, [EventTerm("collision_half_size", Uniform(0.05, 0.06))])


def test_pack_bodies_matches_numpy(rng):
    """kernels.params.pack_bodies on random parameters and mask vs a float64 numpy reference."""
    W, M = 6, 4
    sim = Simulator(Layout.grid(6, 6), num_movers=M, num_worlds=W, device="cpu")
    p = sim.mover_params
    mass = rng.uniform(0.5, 3.0, (W, M))
    inertia = rng.uniform(1e-3, 5e-3, (W, M, 3))
    payload = np.where(rng.random((W, M)) < 0.5, 0.0, rng.uniform(0.0, 0.5, (W, M)))
    offset = rng.uniform(-0.03, 0.03, (W, M, 3))
    known = np.where(rng.random((W, M)) < 0.5, 0.0, rng.uniform(0.0, 0.5, (W, M)))
    k_lin, k_rot = rng.uniform(1, 200, (W, M, 3)), rng.uniform(0.01, 2, (W, M, 3))
    for key, value in (("mass", mass), ("inertia", inertia), ("payload", payload), ("payload_offset", offset),
                       ("payload_known", known), ("k_lin", k_lin), ("k_rot", k_rot)):
        p[key].copy_(torch.as_tensor(value))
    mask = torch.as_tensor(rng.random(W) < 0.6)
    before = sim.model.body.numpy().copy()
    for scale in (False, True):
        sim.commit_mover_params(mask, scale_inertia=scale)
        b = sim.model.body.numpy()
        m_ctrl, i_ctrl = sim.mover.mass, np.asarray(sim.mover.inertia)
        own = inertia * (mass / m_ctrl)[..., None] if scale else inertia
        total = mass + payload
        mu = (mass * payload / total)[..., None]
        r2 = (offset ** 2).sum(-1, keepdims=True)
        ref_inertia = own + mu * (r2 - offset ** 2)
        ref_com = (payload / total)[..., None] * offset
        sel = mask.numpy()
        np.testing.assert_allclose(b["mass"][sel], total[sel], rtol=1e-6)
        np.testing.assert_allclose(b["inv_mass"][sel], 1 / total[sel], rtol=1e-6)
        np.testing.assert_allclose(b["inertia"][sel], ref_inertia[sel], rtol=1e-5)
        np.testing.assert_allclose(b["com"][sel], ref_com[sel], rtol=1e-5, atol=1e-9)
        m_c = m_ctrl + known  # the controller's mass: configured plus the payload it knows of
        np.testing.assert_allclose(b["drive_gain"][sel], m_c[sel] / total[sel], rtol=1e-12)
        np.testing.assert_allclose(b["damp_lin"][sel], 2 * np.sqrt(k_lin[sel] * m_c[sel][..., None]), rtol=1e-5)
        np.testing.assert_allclose(b["damp_rot"][sel], 2 * np.sqrt(k_rot[sel] * i_ctrl), rtol=1e-5)
        assert same(b[~sel], before[~sel])


@pytest.mark.skipif(not cuda_available(), reason="needs CUDA (torch's sync debug mode)")
def test_no_host_sync_on_cuda():
    """Reset and interval events, and the step that reads them, are device work only."""
    terms = PRESETS["sim2real"]["planar"] + [EventTerm("j_max", Uniform(50.0, 90.0), mode="interval", interval_steps=1)]
    env = TrajectoryPlanningEnv(4, device="cuda:0", seed=6, randomization=terms, actuation={"latency_range": [0, 5]})
    mask = torch.tensor([True, False, True, False], device="cuda:0")
    before = env.sim.mover_params["mass"].clone()
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        env.randomizer.reset(mask)
        env.sim.step(40)
    finally:
        torch.cuda.set_sync_debug_mode("default")
    after = env.sim.mover_params["mass"]
    assert torch.equal(after[~mask], before[~mask]) and torch.all(after[mask] != before[mask])


def _pcg(state: int) -> int:
    """Warp's rand_pcg on uint32 (python ints)."""
    b = (state * 747796405 + 2891336453) & 0xFFFFFFFF
    c = (((b >> ((b >> 28) + 4)) ^ b) * 277803737) & 0xFFFFFFFF
    return (c >> 22) ^ c


def _rand_init(seed: int, offset: int) -> int:
    return _pcg((seed + _pcg(offset & 0xFFFFFFFF)) & 0xFFFFFFFF)


class _Stream:
    """A numpy reference of the kernel's generator for one component (Warp's randf / randn): world ``world``'s seed
    for its firing ``counter``, then the component's own ``stream``."""

    def __init__(self, key: int, counter: int, world: int, stream: int):
        seed = _rand_init(_rand_init(key & 0xFFFFFFFF, counter), world)
        self.state = _rand_init(seed, stream)

    def randf(self) -> np.float32:
        self.state = _pcg(self.state)
        return np.float32(self.state >> 8) * np.float32(1.0 / 16777216.0)

    def randn(self) -> float:
        u1 = np.float32(self.randf() + np.float32(5.96e-8))
        u2 = self.randf()
        return float(np.sqrt(np.float32(-2.0) * np.log(u1)) * np.cos(np.float32(2.0 * np.pi) * u2))


def test_fire_terms_matches_numpy(rng):
    """magwarp.kernels.randomize.fire_terms (through the randomiser's reset) on random terms, targets and mask vs a
    numpy reference of its draws, operations and writes; worlds outside the mask keep their rows and counters."""
    lo = rng.uniform(0.8, 1.0, 4)
    terms = [EventTerm("mover_mass", LogUniform(lo[0], lo[0] + 0.3), op="scale", targets=(0, 2)),
             EventTerm("stiffness_rot", Uniform(lo[1], lo[1] + 0.2), op="scale"),
             EventTerm("a_max", Gaussian(rng.uniform(8, 9), 0.5, clip=(7.5, 9.5))),
             EventTerm("payload_mass", Uniform(0.0, lo[2] * 0.3), offset=tuple(rng.uniform(-0.01, 0.01, 3)),
                       known=True, targets=(1,)),
             EventTerm("collision_radius", Uniform(-0.005, 0.0), op="add"),
             EventTerm("mover_mass", Uniform(1.0, 1.5), targets=(2,)),  # the last one that fires sets it
             EventTerm("wall_margin", Gaussian(0.001, 0.0005, clip=(0.0, 0.002)), op="add")]
    n = 7
    env = make(n, terms, seed=int(rng.integers(1 << 30)))
    r = env.randomizer
    before = {k: v.clone() for k, v in r.values.items()}
    counter = r._counter.clone().numpy()
    body0 = env.sim.model.body.numpy().copy()
    mask = torch.as_tensor(rng.random(n) < 0.6)
    mask[0] = True
    r.reset(mask)
    key = int(r._key[0])
    for w in range(n):
        if not mask[w]:
            for k, v in before.items():
                assert torch.equal(r.values[k][w], v[w]), k
            assert np.array_equal(r._counter[w].numpy(), counter[w])
            assert same(env.sim.model.body.numpy()[w], body0[w])
            continue
        assert np.array_equal(r._counter[w].numpy(), counter[w] + 1)  # every target's copy advanced by one
        ref = {k: v[w].clone().double().numpy() for k, v in before.items()}
        for i, t in enumerate(terms):
            field, count = t.field, r._targets[t.field]
            nom = r.nominal[field].double().numpy().reshape(count, -1)
            for m in (t.targets if t.targets is not None else range(count)):
                for k in range(nom.shape[1]):
                    s = _Stream(key, int(counter[w, 0]), w, (i * env.sim.num_movers + m) * 3 + k)
                    d = t.dist
                    if isinstance(d, Gaussian):
                        v = float(np.clip(d.mean + d.std * s.randn(), *d.clip))
                    elif isinstance(d, LogUniform):
                        a, b = math.log(d.lo), math.log(d.hi)
                        v = math.exp(a + float(s.randf()) * (b - a))
                    else:
                        v = d.lo + float(s.randf()) * (d.hi - d.lo)
                    v = nom[m, k] * v if t.op == "scale" else nom[m, k] + v if t.op == "add" else v
                    target = ref[field].reshape(count, -1)
                    target[m, k] = v
        for field, value in ref.items():
            got = r.values[field][w].double().numpy()
            tol = 1e-6 if r.values[field].dtype == torch.float32 or field in ("a_max", "wall_margin") else 1e-12
            np.testing.assert_allclose(got, value.reshape(got.shape), rtol=tol, atol=1e-9, err_msg=field)
        p = env.sim.mover_params
        np.testing.assert_array_equal(p["payload_offset"][w, 1].numpy(), np.asarray(terms[3].offset))
        assert p["payload_known"][w, 1] == p["payload"][w, 1] and p["payload"][w, [0, 2]].eq(0).all()
    # the body rows of the drawn worlds are packed from the new values (pack_bodies' own test checks the packing)
    packed = env.sim.model.body.numpy().copy()
    env.sim.commit_mover_params(mask, scale_inertia=True)
    assert same(env.sim.model.body.numpy(), packed)


def test_vertical_payload_tilts_only_a_tilted_mover():
    """A payload on the vertical axis: on a level mover gravity has no torque (the step skips it: the same bits as the
    payload at the centre); on a tilted one, cross(R com, -M g z) = (sin(roll) com_z M g, 0, 0) in the first cycle."""
    m, p, cz, roll = MASS, 0.3, 0.02, 0.05

    layout = Layout.grid(4, 4)
    centres = layout.tile_centers()[[0, 5, 10]]  # three movers (the kernels other tests compile), on a diagonal

    def run(offset, start_roll):
        pose = np.zeros((1, 3, 6))
        pose[0, :, :2], pose[0, :, 2], pose[0, :, 3] = centres, 0.01, start_roll
        sim = Simulator(layout, num_movers=3, num_worlds=1, device="cpu", start_pose=pose)
        params = sim.mover_params
        params["payload"].fill_(p)
        params["payload_offset"].copy_(torch.tensor(offset, dtype=torch.float64).expand(1, 3, 3))
        sim.commit_mover_params()
        sim.reset()
        sim.step(1 if start_roll else 30, torch.full((1, 3, 2), 3.0))
        return sim

    level, centre = run((0.0, 0.0, cz), 0.0), run((0.0, 0.0, 0.0), 0.0)
    for name in ("pos", "quat", "vel", "omega"):
        assert torch.equal(getattr(level, name), getattr(centre, name)), name
    assert torch.all(level.omega == 0)
    tilted = run((0.0, 0.0, cz), roll)
    total = m + p
    com_z = p / total * cz
    inertia_x = tilted.mover.inertia[0] + m * p / total * cz * cz
    alpha = math.sin(roll) * com_z * total * 9.81 / inertia_x
    np.testing.assert_allclose(tilted.omega[0, 0, 0].item(), alpha * DT, rtol=1e-3)


def _last_writers(terms, targets, mode, steps, interval):
    """Brute force: the (term, target) pairs of ``mode`` that set a value at env step ``steps`` (interval: the terms
    whose period divides it), each the last due term in the table of its field and target."""
    winner = {}
    for i, (field, md) in enumerate(terms):
        if md == mode and (mode != "interval" or steps % interval[i] == 0):
            for m in targets[i]:
                winner[field, m] = i
    return {(i, m) for (_, m), i in winner.items()}


def test_item_plan_matches_the_last_writer_rule(rng):
    """item_plan (the kernel's per-mode items) on random term tables: the startup and reset lists are exactly the
    last writers of each field and target; walking ``later`` over the interval list at each step count picks exactly
    the last due writers (the kernel's ``wins``)."""
    from magwarp.envs.planar_randomization import item_plan

    fields, modes = ["mover_mass", "a_max", "wall_margin", "collision_margin"], ["startup", "reset", "interval"]
    for _ in range(50):
        n = int(rng.integers(1, 9))
        terms = [(fields[rng.integers(len(fields))], modes[rng.integers(3)]) for _ in range(n)]
        targets = [[0] if f.endswith("margin") else sorted(rng.choice(3, int(rng.integers(1, 4)), replace=False))
                   for f, _ in terms]
        interval = [int(rng.integers(1, 5)) for _ in range(n)]
        plans = item_plan(terms, targets)
        for mode in ("startup", "reset"):
            assert all(later == -1 for _, _, later in plans[mode])
            assert [(i, m) for i, m, _ in plans[mode]] == sorted(_last_writers(terms, targets, mode, 0, interval))
        items = plans["interval"]
        assert [(i, m) for i, m, _ in items] == [(i, m) for i, (_, md) in enumerate(terms) if md == "interval"
                                                 for m in targets[i]]
        for steps in range(1, 13):
            def due(q):
                return steps % interval[items[q][0]] == 0

            def wins(q):
                k = items[q][2]
                while k >= 0:
                    if due(k):
                        return False
                    k = items[k][2]
                return due(q)

            got = {items[q][:2] for q in range(len(items)) if wins(q)}
            assert got == _last_writers(terms, targets, "interval", steps, interval), (terms, targets, steps)


@pytest.mark.parametrize("per_thread", [1, 2])
def test_targets_per_thread_give_the_same_bits(per_thread):
    """The GPU's layout (one target per thread: its items, its mover's packing, its counter copy; or two, the last
    thread holding one) against the CPU's (all of a world's in one thread): the same values, bit for bit, with both
    margins of a world drawn (target 0's thread), competing terms and interval terms of two periods."""
    terms = [EventTerm("mover_mass", LogUniform(0.8, 1.25), op="scale"),
             EventTerm("mover_mass", Uniform(2.0, 2.5), targets=(1,)),
             EventTerm("collision_margin", Uniform(0.001, 0.002), mode="reset"),
             EventTerm("wall_margin", Gaussian(0.003, 0.0005, clip=(0.002, 0.004))),
             EventTerm("collision_radius", Uniform(-0.005, 0.0), op="add"),
             EventTerm("payload_mass", Uniform(0.0, 0.2), offset=(0.01, 0.0, 0.0), known=True, targets=(0, 2)),
             EventTerm("a_max", Uniform(1.0, 2.0), mode="interval", interval_steps=2),
             EventTerm("a_max", Uniform(5.0, 6.0), mode="interval", interval_steps=3, targets=(0,)),
             EventTerm("wall_margin", Uniform(0.004, 0.005), mode="interval", interval_steps=3)]
    a, b = make(5, terms, seed=11), make(5, terms, seed=11)
    b.randomizer._per_thread = per_thread
    mask = torch.tensor([True, False, True, True, False])
    for env in (a, b):
        before = env.sim.margins.clone()
        env.randomizer.reset(mask)
        m = env.sim.margins
        assert torch.all((m[mask] != before[mask]).all(1)) and torch.equal(m[~mask], before[~mask])
        assert torch.all((m[mask, 0] >= 0.001) & (m[mask, 0] <= 0.002))
        for _ in range(6):
            env.randomizer.step()
    assert same(a.sim.model.body.numpy(), b.sim.model.body.numpy())
    for key in ("mass", "payload", "payload_offset", "payload_known", "a_max"):
        assert torch.equal(a.sim.mover_params[key], b.sim.mover_params[key]), key
    assert torch.equal(a.sim.margins, b.sim.margins) and torch.equal(a.sim.radii, b.sim.radii)
    assert torch.equal(a.randomizer._counter, b.randomizer._counter)
    assert torch.all((a.sim.margins[:, 1] >= 0.004) & (a.sim.margins[:, 1] <= 0.005))  # step 6: the interval one


def test_limits_only_firing_packs_the_same_bits():
    """A firing that draws only the limits (v_max, a_max, j_max: pack_level's PACK_LIMITS) writes those fields of the
    rows alone; the rows are then bit for bit those of a whole repack (commit_mover_params), and a firing with
    another body field (or none) takes the other levels."""
    from magwarp.envs.planar_randomization import pack_level
    from magwarp.kernels import randomize as krand

    assert pack_level({"j_max", "v_max"}) == krand.PACK_LIMITS
    assert pack_level({"j_max", "mover_mass"}) == pack_level({"payload_mass"}) == krand.PACK_ALL
    assert pack_level({"wall_margin", "collision_radius"}) == pack_level(set()) == krand.PACK_NONE
    terms = [EventTerm("mover_mass", LogUniform(0.8, 1.25), op="scale"),
             EventTerm("payload_mass", Uniform(0.0, 0.2), offset=(0.01, 0.0, 0.002)),
             EventTerm("j_max", Uniform(0.9, 1.0), op="scale", mode="interval", interval_steps=2),
             EventTerm("v_max", Uniform(0.5, 1.0), mode="interval", interval_steps=3, targets=(1,))]
    env = make(4, terms, seed=3)
    r, body = env.randomizer, env.sim.model.body
    for step in range(1, 7):
        before = body.numpy().copy()
        r.step()
        after = body.numpy().copy()
        changed = {f for f in after.dtype.names if not np.array_equal(before[f], after[f])}
        assert changed == ({"j_max"} if step % 2 == 0 else set()) | ({"v_max"} if step % 3 == 0 else set()), step
        env.sim.commit_mover_params(None, scale_inertia=True)
        assert same(body.numpy(), after), step
