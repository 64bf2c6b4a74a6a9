"""mujoco-warp backend vs float64 MuJoCo C (same MJCF, same control law), masked reset, input errors.

One backend per module (mujoco-warp compiles once: ~70 s cold on CPU, ~1 s warm with WARP_CACHE_PATH).
"""

import numpy as np
import pytest
import torch
import warp as wp

from magwarp.layout import Layout
from magwarp.mjcf import ObjectSpec, generate_mjcf
from magwarp.physics import ControlParams, MjwBackend, PhysicsInputError
from magwarp.physics import oracle

wp.config.quiet = True

# A mover 1 mm behind a box on a full 3x3 grid; low floor friction so the box slides smoothly when pushed.
XML = generate_mjcf(Layout.grid(3, 3), 1, mover_xy=[[0.12, 0.40]],
                    objects=[ObjectSpec("box", friction=(0.1, 0.005, 0.0001))], object_xy=[[0.2585, 0.36]])
CYCLES = 10
WORLDS = 3




def _settle_box(b: MjwBackend) -> None:
    # Start the box 10 um into the floor: at exactly z = depth the contact distance is ~1e-10, which float64 keeps
    # and float32 drops, and that first-cycle difference would dominate the comparison.
    b.init_object_qpos[:, 0, 2] = 0.01999


@pytest.fixture(scope="module")
def backend():
    b = MjwBackend(XML, WORLDS, control=ControlParams(num_cycles=CYCLES), device="cpu")
    _settle_box(b)
    return b


def _run(b: MjwBackend, actions: np.ndarray) -> np.ndarray:
    """actions [steps, W, M, 2] -> qpos after each step [steps, W, nq]."""
    out = []
    for a in actions:
        b.step(torch.as_tensor(a, dtype=torch.float32))
        out.append(b.qpos_t.numpy().copy())
    return np.array(out)


def test_free_motion_and_push_match_mujoco_c(backend):
    # 250 cycles, pushing from cycle ~26 on (measured max error: 5e-6 after 150 cycles, 5e-5 after 250). Beyond,
    # the sliding box starts rocking on 1-3 corner contacts, marginal contacts (depth ~1e-7) flip in or out between
    # float32 and float64, and the runs part ways (3e-4 after 350 cycles), although MuJoCo C itself is insensitive
    # to float32 rounding of its state here.
    steps, push_steps = 25, 25
    acts = np.zeros((steps, WORLDS, 1, 2))
    acts[:, 0, 0] = [1.0, 0.0]  # world 0: push the box (+x)
    acts[:, 1, 0] = [-10.0, 6.0]  # world 1: free flight, clipped to |a| = 10, then capped at 2 m/s (reached at 0.2 s)
    acts[:8, 2, 0] = [0.0, -20.0]  # world 2: free flight, brake after 80 cycles
    acts[8:, 2, 0] = [-3.0, 10.0]
    backend.reset()
    got = _run(backend, acts)
    for w in range(WORLDS):
        n = push_steps if w == 0 else steps
        want, _ = oracle.rollout(XML, acts[:n, w], backend.control, init_qpos=backend.init_qpos.numpy()[w])
        err = np.abs(got[:n, w] - want).max()
        assert err < 1e-4, f"world {w}: max |qpos - MuJoCo C| = {err:.3g}"
    # the scenario exercised what it claims: box pushed, free movers far from the box with speed capped
    assert got[push_steps - 1, 0, 7] - got[0, 0, 7] > 5e-3
    want, vel = oracle.rollout(XML, acts[:, 1], backend.control, init_qpos=backend.init_qpos.numpy()[1])
    assert np.linalg.norm(vel[-1, :2]) == pytest.approx(2.0, abs=1e-6)
    assert np.abs(got[-1, 1, :2] - got[0, 1, :2]).max() > 0.05


def test_jerk_mode_matches_mujoco_c():
    control = ControlParams(num_cycles=CYCLES, jerk=True)
    b = MjwBackend(XML, 1, control=control, device="cpu")
    _settle_box(b)
    b.reset()
    acts = np.zeros((30, 1, 1, 2))
    acts[:10, 0, 0] = [-150.0, 20.0]  # clipped to |j| = 100, acceleration capped at 10
    acts[10:20, 0, 0] = [80.0, -10.0]
    got = _run(b, acts)
    want, _ = oracle.rollout(XML, acts[:, 0], control, init_qpos=b.init_qpos.numpy()[0])
    err = np.abs(got[:, 0] - want).max()
    assert err < 1e-4, f"max |qpos - MuJoCo C| = {err:.3g}"
    assert np.abs(b.acc_t.numpy()).max() <= 10.0 + 1e-4


def test_hover_and_attitude_hold_converge(backend):
    # start tilted and too high: the impedance law brings z to hover_z and the attitude to level (critical damping)
    backend.init_mover_qpos[:, 0, 2] = backend.hover_z[0] + 0.003
    q = np.array([np.cos(0.05), np.sin(0.05), 0.0, 0.0])  # 0.1 rad roll
    backend.init_mover_qpos[:, 0, 3:] = torch.as_tensor(q, dtype=torch.float32)
    backend.reset()
    got = _run(backend, np.zeros((100, WORLDS, 1, 2)))
    want, _ = oracle.rollout(XML, np.zeros((100, 1, 2)), backend.control, init_qpos=backend.init_qpos.numpy()[0],
                             hover_z=backend.hover_z)
    assert np.abs(got[:, 0] - want).max() < 1e-4
    assert got[-1, 0, 2] == pytest.approx(backend.hover_z[0], abs=2e-5)
    assert abs(got[-1, 0, 4]) < 1e-3  # roll decayed from 0.05 (quaternion x)
    backend.init_qpos_t.copy_(torch.as_tensor(np.tile(backend.mjm.qpos0, (WORLDS, 1)), dtype=torch.float32))
    _settle_box(backend)


def test_reset_by_mask_touches_only_masked_worlds(backend):
    backend.reset()
    a = torch.zeros(WORLDS, 1, 2)
    a[:, 0, 1] = torch.tensor([2.0, -3.0, 4.0])
    backend.step(a)
    before_q = backend.qpos_t.clone()
    before_v = backend.qvel_t.clone()
    start = backend.init_qpos_t.clone()
    backend.init_mover_qpos[1, 0, :2] = torch.tensor([0.5, 0.5])
    backend.init_object_qpos[1, 0, :2] = torch.tensor([0.2, 0.2])
    backend.reset(torch.tensor([False, True, False]))
    q, v = backend.qpos_t, backend.qvel_t
    assert torch.equal(q[[0, 2]], before_q[[0, 2]]) and torch.equal(v[[0, 2]], before_v[[0, 2]])
    assert torch.equal(q[1], backend.init_qpos_t[1]) and not torch.equal(q[1], before_q[1])
    assert q[1, 0] == 0.5 and q[1, 7] == pytest.approx(0.2) and torch.all(v[1] == 0)
    assert torch.all(backend.acc_t[1] == 0) and torch.any(backend.acc_t[0] != 0)
    # the reset world restarts cleanly: its next step equals a fresh world started from the same pose
    backend.step(a)
    want, _ = oracle.rollout(XML, a[1:2].numpy(), backend.control, init_qpos=backend.init_qpos.numpy()[1])
    assert np.abs(backend.qpos_t[1].numpy() - want[-1]).max() < 1e-5
    backend.init_qpos_t.copy_(start)


def test_views_alias_mujoco_warp_data(backend):
    assert backend.mover_qpos.shape == (WORLDS, 1, 7) and backend.object_qvel.shape == (WORLDS, 1, 6)
    assert backend.mover_qpos.data_ptr() == backend.qpos_t.data_ptr()
    backend.reset()
    np.testing.assert_allclose(backend.object_qpos[0, 0, :3].numpy(), [0.2585, 0.36, 0.01999], atol=1e-6)
    backend.mover_qpos[2, 0, 1] = 0.45  # writes through to mujoco-warp's qpos
    assert backend.data.qpos.numpy()[2, 1] == pytest.approx(0.45)


def test_bad_inputs_raise_clear_errors(backend):
    with pytest.raises(PhysicsInputError, match=r"shape \(3, 1, 2\) or \(3, 2\), got \(2, 2\)"):
        backend.step(torch.zeros(2, 2))
    with pytest.raises(PhysicsInputError, match="floating-point.*torch.int64"):
        backend.step(torch.zeros(3, 2, dtype=torch.int64))
    with pytest.raises(PhysicsInputError, match="numpy array"):
        backend.step(np.zeros((3, 2)))
    bad = torch.zeros(3, 1, 2)
    bad[2, 0, 1] = float("nan")
    with pytest.raises(PhysicsInputError, match="nan at world 2, mover 0, axis 1"):
        backend.step(bad)
    if torch.device("meta") != backend.torch_device:
        with pytest.raises(PhysicsInputError, match="device meta"):
            backend.step(torch.zeros(3, 2, device="meta"))
    with pytest.raises(PhysicsInputError, match="torch.bool"):
        backend.reset(torch.zeros(3))
    with pytest.raises(PhysicsInputError, match=r"shape \(3,\)"):
        backend.reset(torch.zeros(4, dtype=torch.bool))
    with pytest.raises(PhysicsInputError, match="num_cycles"):
        ControlParams(num_cycles=0)
    with pytest.raises(PhysicsInputError, match="v_max"):
        ControlParams(v_max=float("nan"))
    for worlds in (0, -2, 2.5, float("nan"), True, "3"):  # checked before any model is read or built
        with pytest.raises(PhysicsInputError, match=f"num_worlds must be a positive integer, got {worlds!r}"):
            MjwBackend("<mujoco/>", worlds, device="cpu")


def _push_both_engines(xml: str, steps: int) -> tuple[np.ndarray, np.ndarray, MjwBackend]:
    """World 0's push (+x) on ``xml`` in mujoco-warp and in MuJoCo C: qpos after each step, ``[steps, nq]`` each."""
    b = MjwBackend(xml, 1, control=ControlParams(num_cycles=CYCLES), device="cpu")
    _settle_box(b)
    acts = np.zeros((steps, 1, 1, 2))
    acts[:, 0, 0] = [1.0, 0.0]
    b.reset()
    got = _run(b, acts)[:, 0]
    want, _ = oracle.rollout(xml, acts[:, 0], b.control, init_qpos=b.init_qpos.numpy()[0])
    return got, want, b


def test_cg_solver_push_matches_mujoco_c():
    # The push envs solve contacts with CG on CPU (solver="auto"): the same push, both engines on CG.
    xml = XML.replace('cone="elliptic" solver="Newton"', 'cone="elliptic" solver="CG"')
    assert 'solver="CG"' in xml
    got, want, _ = _push_both_engines(xml, 25)
    err = np.abs(got - want).max(axis=1)
    # CG stops at MuJoCo's tolerance at different iterates in float32 and float64: the gap peaks at 1.1e-4 (about
    # 1e-4, as for Newton) and does not grow: 4e-5 after 250 cycles
    assert err.max() < 2e-4 and err[-1] < 1e-4, err
    assert got[-1, 7] - got[0, 7] > 5e-3  # the box was pushed


@pytest.mark.parametrize("jerk", [False, True])
def test_yaw_drive_matches_mujoco_c_and_respects_limits(jerk):
    # A free mover (no object in reach) spun up against a 0.5 rad position limit, then back the other way.
    control = ControlParams(num_cycles=CYCLES, jerk=jerk, rotation=True, p_max_c=0.5, v_max_c=10.0, a_max_c=50.0,
                            j_max_c=2000.0)
    xml = generate_mjcf(Layout.grid(3, 3), 1, mover_xy=[[0.36, 0.36]])
    b = MjwBackend(xml, 1, control=control, device="cpu")
    acts = np.zeros((50, 1, 1, 3))
    acts[:12, 0, 0] = [2.0, 0.0, 2000.0 if jerk else 50.0]
    acts[12:, 0, 0] = [-2.0, 1.0, -2000.0 if jerk else -50.0]
    b.reset()
    got = _run(b, acts)[:, 0]
    want, vel = oracle.rollout(xml, acts[:, 0], control, init_qpos=b.init_qpos.numpy()[0])
    assert np.abs(got - want).max() < 1e-4
    yaw = 2 * np.arctan2(want[:, 6], want[:, 3])  # level mover: quaternion (cos, 0, 0, sin) of half the yaw
    assert yaw.max() > 0.3 and yaw.min() < -0.3  # it turned both ways ...
    assert np.abs(yaw).max() < 0.5 + 1e-3  # ... and stopped at the limit
    assert np.abs(vel[:, 5]).max() <= 10.0 + 1e-6
    with pytest.raises(PhysicsInputError, match="shape"):
        b.step(torch.zeros(1, 1, 2))
    with pytest.raises(PhysicsInputError, match="p_max_c"):
        ControlParams(rotation=True, p_max_c=4.0)


def test_capped_solver_iterations_match_mujoco_c_with_the_same_cap():
    # A cap is part of the model (MJCF <option iterations ls_iterations>): MuJoCo C and mujoco-warp run the same
    # truncated Newton solve, so they still agree.
    xml = XML.replace('iterations="100" ls_iterations="50"', 'iterations="2" ls_iterations="4"')
    assert 'iterations="2"' in xml
    got, want, b = _push_both_engines(xml, 20)
    assert np.abs(got - want).max() < 1e-4
    assert got[-1, 7] - got[0, 7] > 5e-3
    assert int(b.data.solver_niter.numpy().max()) <= 2
