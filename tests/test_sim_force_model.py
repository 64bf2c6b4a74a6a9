"""A custom force model (``examples/custom_force_model.py``: coil currents in ``force_aux`` + viscous drag) swapped in
through ``Simulator(force_model=...)``: its effect matches a float64 numpy integration of the same law."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from magwarp import reference as ref
from magwarp.layout import Layout
from magwarp.sim import Simulator

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "custom_force_model.py"


@pytest.fixture(scope="module")
def example():
    spec = importlib.util.spec_from_file_location("custom_force_model_example", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("fused", [True, False])
def test_coil_model_matches_numpy(example, fused, rng):
    w, m, n = 3, 2, 300
    k_coil, c_drag = float(example.K_COIL), float(example.C_DRAG)
    sim = Simulator(Layout.grid(8, 4), num_movers=m, num_worlds=w, force_model=example.coil_force, force_aux_dim=2,
                    device="cpu", stop_on_collision=False, fused_max_movers=16 if fused else 0)
    assert sim._fused == fused
    currents = rng.uniform(-1.0, 1.0, (w, m, 2))
    currents[0] = 0.0  # world 0: no current
    cmd = rng.uniform(-1.0, 1.0, (w, m, 2))
    sim.force_aux.copy_(torch.as_tensor(currents, dtype=torch.float32))
    sim.set_command(torch.as_tensor(cmd, dtype=torch.float32))
    currents, cmd = (np.asarray(x, np.float32).astype(np.float64) for x in (currents, cmd))
    p = sim.start_pos.numpy()[..., :2].astype(np.float64)
    v = np.zeros((w, m, 2))
    mass = sim.mover.mass
    got_v, got_p, want_v, want_p = [], [], [], []
    for c in range(n):
        sim.step(1)
        a_cmd, _, _ = ref.planar_cycle(v, np.zeros_like(v), cmd, dt=1e-3, v_max=2.0, a_max=10.0, j_max=100.0,
                                       jerk_mode=False)
        v = v + 1e-3 * (a_cmd + (k_coil * currents - c_drag * v) / mass)
        p = p + 1e-3 * v
        if c % 10 == 9:
            got_v.append(sim.vel[..., :2].numpy().copy())
            got_p.append(sim.pos[..., :2].numpy().copy())
            want_v.append(v)
            want_p.append(p)
    np.testing.assert_allclose(np.array(got_v), np.array(want_v), atol=2e-6, err_msg=str(rng))
    np.testing.assert_allclose(np.array(got_p), np.array(want_p), atol=2e-6, err_msg=str(rng))
    # The custom terms matter: the velocity is far from what the command alone gives (cmd * t).
    assert np.abs(np.array(got_v)[-1] - cmd * n * 1e-3).max() > 0.05, rng
    # The rest of the default model is kept: height and attitude are held.
    np.testing.assert_allclose(sim.pos[..., 2].numpy(), sim.model.hover_z, atol=1e-6)
    np.testing.assert_allclose(sim.quat.numpy(), sim.start_quat.numpy(), atol=1e-6)


def test_coil_model_terminal_speed(example):
    """Constant current, no command: v(t) = K i / C (1 - exp(-C t / m)), semi-implicit Euler within 0.5%."""
    sim = example.make_sim(num_worlds=1, device="cpu")
    sim.force_aux[0, :, 0] = torch.tensor([0.5, 1.0])
    sim.step(600)
    tau = sim.mover.mass / float(example.C_DRAG)
    exact = float(example.K_COIL) * np.array([0.5, 1.0]) / float(example.C_DRAG) * (1 - np.exp(-0.6 / tau))
    np.testing.assert_allclose(sim.vel[0, :, 0].numpy(), exact, rtol=5e-3)
    np.testing.assert_allclose(sim.vel[0, :, 1].numpy(), 0.0, atol=1e-9)


def test_default_model_ignores_force_aux_and_coexists(example):
    """The same inputs under the default model do nothing; both models live side by side in one process."""
    custom = example.make_sim(num_worlds=1, device="cpu")
    default = Simulator(Layout.grid(6, 2), num_movers=2, start_xy=[[0.12, 0.12], [0.12, 0.36]], force_aux_dim=2,
                        device="cpu", stop_on_collision=False)
    for sim in (custom, default):
        sim.force_aux.fill_(1.0)
        sim.step(50)
    assert float(torch.linalg.norm(default.vel[..., :2])) == 0.0
    assert float(custom.vel[0, 0, 0]) > 0.05
    assert custom._advance_kernel is not default._advance_kernel
