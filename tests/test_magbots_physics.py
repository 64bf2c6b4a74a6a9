"""6D-platform MagBot on the mujoco-warp backend: MJCF consistency, trajectories vs float64 MuJoCo C, pose maps.

One small model (one platform, two movers); mujoco-warp compiles once per process (WARP_CACHE_PATH keeps it warm).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch
import warp as wp
from scipy.spatial.transform import Rotation

from magwarp.layout import Layout, LayoutError
from magwarp.magbots import MagBotLimitError, PlatformGeometry, platform_fk
from magwarp.magbots.mjcf import PlatformJoints, generate_platform_mjcf
from magwarp.physics import ControlParams, MjwBackend

from magbots_helpers import rollout_vs_mujoco_c  # noqa: E402  (tests/ is on sys.path)

wp.config.quiet = True
XML = generate_platform_mjcf(Layout.grid(4, 4), [[0.48, 0.48]])
MOVER_Z = 0.01
G = PlatformGeometry()


def _random_pose(rng, n: int) -> torch.Tensor:
    lo, hi = G.height_range
    p = np.empty((n, 1, 6))
    p[:, 0, :2] = rng.uniform(0.35, 0.6, (n, 2))
    p[:, 0, 2] = MOVER_Z + rng.uniform(lo + 0.005, hi - 0.005, n)
    p[:, 0, 3:5] = rng.uniform(-0.9 * G.max_tilt, 0.9 * G.max_tilt, (n, 2))
    p[:, 0, 5] = rng.uniform(-math.pi, math.pi, n)
    return torch.as_tensor(p)


def test_written_qpos_satisfies_every_constraint_and_the_site_pose(rng):
    mjm = mujoco.MjModel.from_xml_string(XML)
    mjd = mujoco.MjData(mjm)
    pj = PlatformJoints(mjm)
    site = mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_SITE, "p0_platform_site")
    poses = _random_pose(rng, 20)
    q = torch.as_tensor(mjm.qpos0).repeat(20, 1)
    pj.write_qpos(q, poses, MOVER_Z)
    np.testing.assert_allclose(pj.pose(q).numpy(), poses.numpy(), atol=1e-12, err_msg=str(rng))
    for w in range(20):
        mjd.qpos[:] = q[w].numpy()
        mujoco.mj_forward(mjm, mjd)
        assert np.abs(mjd.efc_pos[: mjd.ne]).max() < 1e-9, (w, str(rng))  # welds, connect, gears all closed
        euler = Rotation.from_matrix(mjd.site_xmat[site].reshape(3, 3)).as_euler("xyz")
        got = np.concatenate([mjd.site_xpos[site], euler])
        np.testing.assert_allclose(got, poses[w, 0].numpy(), atol=1e-9, err_msg=f"world {w} {rng}")
        movers = np.stack([mjd.qpos[0:3], mjd.qpos[7:10]])
        yaws = [2 * math.atan2(mjd.qpos[6], mjd.qpos[3]), 2 * math.atan2(mjd.qpos[13], mjd.qpos[10])]
        fk = platform_fk(torch.as_tensor(np.concatenate([movers, np.array(yaws)[:, None]], 1)))
        np.testing.assert_allclose(fk.numpy(), poses[w, 0].numpy(), atol=1e-9, err_msg=f"world {w} {rng}")
    with pytest.raises(MagBotLimitError, match="'roll'"):
        bad = poses.clone()
        bad[3, 0, 3] = 0.5
        pj.write_qpos(q, bad, MOVER_Z)
    with pytest.raises(MagBotLimitError, match="shape"):
        pj.write_qpos(q, poses[:, 0], MOVER_Z)


def test_platform_trajectories_match_mujoco_c(rng):
    control = ControlParams(num_cycles=10, rotation=True)
    b = MjwBackend(XML, 2, control=control, device="cpu")
    pj = PlatformJoints(b.mjm)
    q = b.init_qpos_t.double().clone()
    start = torch.tensor([[[0.48, 0.48, MOVER_Z + 0.22, 0.0, 0.0, 0.0]],
                          [[0.5, 0.45, MOVER_Z + 0.25, 0.1, -0.12, 0.6]]],
                         dtype=torch.float64)
    pj.write_qpos(q, start, MOVER_Z)
    b.init_qpos_t.copy_(q)
    b.reset()
    steps = 30  # 300 cycles
    acts = np.zeros((steps, 2, 2, 3))
    acts[:10, 0] = [[2.0, 1.0, 0.0], [2.0, 1.0, 0.0]]  # world 0: carry the platform, then spread the movers (it sinks)
    acts[10:20, 0] = [[-3.0, -1.0, 0.0], [-1.0, -1.0, 0.0]]
    acts[20:, 0] = [[0.5, 0.0, 0.0], [-0.5, 0.0, 0.0]]
    acts[:, 1, :, 2] = np.where(np.arange(steps) < 15, 1.0, -1.0)[:, None] * np.array([30.0, -30.0])  # world 1: tilt
    acts[:, 1, :, :2] = rng.uniform(-1.0, 1.0, (steps, 2, 2))
    got, errors = rollout_vs_mujoco_c(b, XML, acts)
    assert max(errors) < 1e-4, f"max |qpos - MuJoCo C| per world: {errors} ({rng})"
    pose = pj.pose(torch.as_tensor(got[:, :]).reshape(steps * 2, -1)).reshape(steps, 2, 6)
    # the runs did what they claim: world 0's platform travelled and sank, world 1's tilted both ways
    assert float(pose[9, 0, 0] - pose[0, 0, 0]) > 0.005 and float(pose[-1, 0, 2] - pose[9, 0, 2]) < -0.005
    assert float(pose[:, 1, 3].max() - pose[:, 1, 3].min()) > 0.02
    assert float(pose[:, 1, 4].max() - pose[:, 1, 4].min()) > 0.02


def test_bad_platform_models_raise_clear_errors():
    with pytest.raises(LayoutError, match="platform_xy"):
        generate_platform_mjcf(Layout.grid(2, 2), [[0.1, float("nan")]])
    no_platform = mujoco.MjModel.from_xml_string("<mujoco><worldbody/></mujoco>")
    with pytest.raises(LayoutError, match="p0_base"):
        PlatformJoints(no_platform)
