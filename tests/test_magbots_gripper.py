"""Two-mover gripper MagBot: jaw kinematics (numpy float64 reference, inverse), MJCF consistency, mujoco-warp vs
float64 MuJoCo C."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch
import warp as wp

from magwarp.layout import Layout
from magwarp.magbots import MagBotLimitError
from magwarp.magbots.gripper import (GripperGeometry, GripperJoints, generate_gripper_mjcf, gripper_limit_violations,
                                     jaw_width, lever_angle, mover_distance)
from magwarp.physics import ControlParams, MjwBackend

from magbots_helpers import rollout_vs_mujoco_c  # noqa: E402  (tests/ is on sys.path)

wp.config.quiet = True
G = GripperGeometry()
XML = generate_gripper_mjcf(Layout.grid(4, 4), [[0.4, 0.48]])


def width_reference(d: float, g: GripperGeometry = G) -> float:
    """Float64 numpy: find the lever angle where the rod closes the loop (bisection), then the fingertip gap."""
    def gap(theta):
        lever = np.array([-g.hinge_back - g.lever * math.cos(theta), g.hinge_side + g.lever * math.sin(theta)])
        return np.linalg.norm(lever - np.array([d, g.pin_side])) - g.rod

    lo, hi = 1e-6, math.pi - 1e-6  # the lever swings toward the slider as theta grows: gap falls on (0, pi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if gap(mid) > 0 else (lo, mid)
    theta = 0.5 * (lo + hi)
    tip_y = g.hinge_side + g.finger * math.sin(theta - g.bend)
    return 2 * tip_y - 2 * g.pad


def test_jaw_kinematics_match_the_reference_and_invert(rng):
    d = rng.uniform(G.min_distance, G.max_distance, 200)
    w = jaw_width(torch.as_tensor(d), G).numpy()
    np.testing.assert_allclose(w, [width_reference(x) for x in d], rtol=0, atol=1e-12, err_msg=str(rng))
    back = mover_distance(torch.as_tensor(w), G).numpy()
    np.testing.assert_allclose(back, d, rtol=0, atol=1e-9, err_msg=str(rng))
    lo, hi = G.width_range
    assert 0 <= lo < 0.02 and hi > 0.15  # closes to under 2 cm and opens past 15 cm
    assert np.all(np.diff(jaw_width(torch.linspace(G.min_distance, G.max_distance, 50, dtype=torch.float64), G)) > 0)
    viol = gripper_limit_violations(torch.tensor([lo - 1e-3, 0.1, hi + 1e-3, float("nan")]), G)
    assert viol["width_min"].tolist() == [True, False, False, False]
    assert viol["width_max"].tolist() == [False, False, True, False]
    assert viol["non_finite"].tolist() == [False, False, False, True]
    assert torch.isfinite(lever_angle(torch.tensor([G.min_distance, G.max_distance]), G)).all()
    with pytest.raises(MagBotLimitError, match="cannot close the loop"):
        GripperGeometry(rod=0.4)


def test_written_qpos_closes_every_loop_and_sets_the_jaw(rng):
    mjm = mujoco.MjModel.from_xml_string(XML)
    mjd = mujoco.MjData(mjm)
    gj = GripperJoints(mjm)
    lo, hi = G.width_range
    n = 10
    st = np.stack([rng.uniform(0.3, 0.6, n), rng.uniform(0.3, 0.6, n), rng.uniform(-math.pi, math.pi, n),
                   rng.uniform(lo, hi, n)], 1)[:, None]
    q = torch.as_tensor(mjm.qpos0).repeat(n, 1)
    gj.write_qpos(q, torch.as_tensor(st), 0.01)
    np.testing.assert_allclose(gj.state(q).numpy(), st, atol=1e-12, err_msg=str(rng))
    pads = [mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_GEOM, f"g0_pad_{s}") for s in "pm"]
    for w in range(n):
        mjd.qpos[:] = q[w].numpy()
        mujoco.mj_forward(mjm, mjd)
        assert np.abs(mjd.efc_pos[: mjd.ne]).max() < 1e-9, (w, str(rng))
        gap = np.linalg.norm(mjd.geom_xpos[pads[0]] - mjd.geom_xpos[pads[1]]) - 2 * G.pad
        assert gap == pytest.approx(st[w, 0, 3], abs=1e-9), (w, str(rng))
    with pytest.raises(MagBotLimitError, match="'width_max'"):
        bad = torch.as_tensor(st).clone()
        bad[2, 0, 3] = hi + 0.01
        gj.write_qpos(q, bad, 0.01)


def test_gripper_trajectories_match_mujoco_c():
    control = ControlParams(num_cycles=10)
    b = MjwBackend(XML, 2, control=control, device="cpu")
    gj = GripperJoints(b.mjm)
    q = b.init_qpos_t.double().clone()
    gj.write_qpos(q, torch.tensor([[[0.4, 0.48, 0.0, 0.05]], [[0.45, 0.4, 0.7, 0.15]]], dtype=torch.float64), 0.01)
    b.init_qpos_t.copy_(q)
    b.reset()
    steps = 30  # 300 cycles
    acts = np.zeros((steps, 2, 2, 2))
    acts[:10, 0, 1] = [2.0, 0.0]  # world 0: B pulls away (the jaw opens), then both carry it sideways
    acts[10:20, 0] = [[0.0, 1.5], [-2.0, 1.5]]
    acts[20:, 0] = [[0.0, -1.5], [0.0, -1.5]]
    acts[:15, 1, 0] = [1.2, 0.9]  # world 1: A closes in on B (the jaw closes), then it backs off
    acts[15:, 1, 0] = [-1.2, -0.9]
    got, errors = rollout_vs_mujoco_c(b, XML, acts)
    assert max(errors) < 1e-4, f"max |qpos - MuJoCo C| per world: {errors}"
    width = gj.state(torch.as_tensor(got).reshape(steps * 2, -1)).reshape(steps, 2, 4)[..., 3]
    assert float(width[9, 0] - width[0, 0]) > 0.01  # opened
    assert float(width[14, 1] - width[0, 1]) < -0.01  # closed
