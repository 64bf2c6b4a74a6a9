"""Simulator start poses: full 6-DoF poses per world, the public ``validate_starts`` switch, and NaN/inf refused
with an error naming the value (at construction and in ``set_start_poses``)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from magwarp import reference as ref
from magwarp.layout import Layout, LayoutError
from magwarp.sim import Simulator

L3 = Layout.grid(3, 3)


def quat_rpy(roll, pitch, yaw):
    """Reference: R = Rz(yaw) Ry(pitch) Rx(roll) as a quaternion product (x, y, z, w)."""
    qx = np.array([np.sin(roll / 2), 0, 0, np.cos(roll / 2)])
    qy = np.array([0, np.sin(pitch / 2), 0, np.cos(pitch / 2)])
    qz = np.array([0, 0, np.sin(yaw / 2), np.cos(yaw / 2)])
    return ref.quat_mul(ref.quat_mul(qz, qy), qx)


def test_six_dof_start_poses_per_world(rng):
    w, m = 3, 2
    pose = np.zeros((w, m, 6))
    pose[..., :2] = [[0.12, 0.12], [0.6, 0.6]]
    pose[..., :2] += rng.uniform(-0.01, 0.01, (w, m, 2))
    pose[..., 2] = rng.uniform(0.005, 0.02, (w, m))
    pose[..., 3:5] = rng.uniform(-0.2, 0.2, (w, m, 2))
    pose[..., 5] = rng.uniform(-np.pi, np.pi, (w, m))
    sim = Simulator(L3, num_worlds=w, start_pose=pose, device="cpu")
    np.testing.assert_allclose(sim.pos.numpy(), pose[..., :3], atol=1e-6, err_msg=str(rng))
    want = np.array([[quat_rpy(*pose[i, k, 3:]) for k in range(m)] for i in range(w)])
    got = sim.quat.numpy()
    sign = np.sign(np.sum(got * want, axis=-1, keepdims=True))
    np.testing.assert_allclose(got * sign, want, atol=1e-6, err_msg=str(rng))
    np.testing.assert_allclose(sim.yaw.numpy(), pose[..., 5], atol=1e-5, err_msg=str(rng))
    # the start pose is the impedance target: at rest there, the mover stays
    sim.step(40)
    np.testing.assert_allclose(sim.pos.numpy(), pose[..., :3], atol=1e-5, err_msg=str(rng))
    # shared by every world, and replaced later with set_start_poses (torch input too)
    sim.set_start_poses(start_pose=torch.as_tensor(pose[0]))
    sim.reset()
    np.testing.assert_allclose(sim.pos.numpy(), np.broadcast_to(pose[0, :, :3], (w, m, 3)), atol=1e-6)


def test_start_xy_and_yaw_still_hover_level():
    sim = Simulator(L3, start_xy=[[0.12, 0.36]], start_yaw=[0.5], device="cpu")
    np.testing.assert_allclose(sim.pos[0, 0].numpy(), [0.12, 0.36, sim.mover.hover_z], atol=1e-7)
    np.testing.assert_allclose(sim.quat[0, 0].numpy(), [0, 0, np.sin(0.25), np.cos(0.25)], atol=1e-7)


def test_validate_starts_is_public():
    overlapping = [[0.12, 0.12], [0.2, 0.12]]
    with pytest.raises(LayoutError, match="overlap"):
        Simulator(L3, start_xy=overlapping, device="cpu")
    sim = Simulator(L3, start_xy=overlapping, device="cpu", validate_starts=False)
    sim.check_collisions()
    assert sim.flags.numpy().tolist() == [[1, 1]]


@pytest.mark.parametrize("kwargs, match", [
    (dict(start_xy=[[float("nan"), 0.12]]), "start_xy contains a non-finite value at index [0, 0, 0]: nan"),
    (dict(start_xy=[[0.12, float("inf")]]), "start_xy contains a non-finite value at index [0, 0, 1]: inf"),
    (dict(start_xy=[[0.12, 0.12]], start_yaw=[float("nan")]), "start_yaw contains a non-finite value at index [0, 0]"),
    (dict(start_pose=[[0.12, 0.12, 0.01, 0.0, float("nan"), 0.0]]), "start_pose contains a non-finite value at "
                                                                     "index [0, 0, 4]: nan"),
    (dict(start_pose=[[0.12, 0.12, 1e39, 0.0, 0.0, 0.0]]), "start_pose contains a non-finite value at index [0, 0, 2]"),
    (dict(start_pose=[[0.12, 0.12, 0.01]]), r"start_pose must have shape \(num_movers, 6\)"),
    (dict(start_pose=[[0.12, 0.12, 0.01, 0, 0, 0]], start_xy=[[0.1, 0.1]]), "either start_pose or start_xy"),
])
def test_bad_start_poses_name_the_value(kwargs, match):
    with pytest.raises(ValueError, match=re.escape(match) if "[" in match else match):
        Simulator(L3, device="cpu", **kwargs)


def test_set_start_poses_refuses_nan_and_keeps_the_old_poses():
    sim = Simulator(L3, start_xy=[[0.12, 0.12]], device="cpu")
    before = sim.start_pos.clone()
    with pytest.raises(LayoutError, match=re.escape("start_xy contains a non-finite value at index [0, 0, 1]: nan")):
        sim.set_start_poses([[0.36, float("nan")]])
    with pytest.raises(LayoutError, match="start_pose contains a non-finite value"):
        sim.set_start_poses(start_pose=torch.tensor([[0.36, 0.36, 0.01, float("inf"), 0.0, 0.0]]))
    with pytest.raises(ValueError, match="give start_xy"):
        sim.set_start_poses()
    assert torch.equal(sim.start_pos, before)
