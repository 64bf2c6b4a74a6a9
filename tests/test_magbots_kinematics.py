"""6D-platform MagBot kinematics: float64 numpy reference, IK/FK round trip, limits, MagBotSim's IK."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from magwarp.magbots import MagBotLimitError, PlatformGeometry, check_platform_pose, platform_fk, platform_ik
from magwarp.magbots import platform_limit_violations

G = PlatformGeometry()


def random_poses(rng, n: int, mover_z: np.ndarray, g: PlatformGeometry = G) -> np.ndarray:
    """Platform poses inside every limit: [n, 6]."""
    lo, hi = g.height_range
    pose = np.empty((n, 6))
    pose[:, :2] = rng.uniform(-2.0, 2.0, (n, 2))
    pose[:, 2] = mover_z + rng.uniform(lo, hi, n)
    pose[:, 3:5] = rng.uniform(-g.max_tilt, g.max_tilt, (n, 2))
    pose[:, 5] = rng.uniform(-math.pi, math.pi, n)
    return pose


def ik_reference(pose: np.ndarray, mover_z: np.ndarray, g: PlatformGeometry = G) -> np.ndarray:
    """Float64 numpy IK from the linkage's geometry: lift angle theta from the height, then the link's horizontal
    reach, the movers on the platform's x axis, and the gear trains for the tilt."""
    out = np.empty((len(pose), 2, 4))
    for i, (x, y, z, roll, pitch, yaw) in enumerate(pose):
        theta = math.asin((z - mover_z[i] - g.lift_offset) / g.link_length)
        half = g.link_offset + g.link_length * math.cos(theta)
        axis = np.array([math.cos(yaw), math.sin(yaw)])
        out[i, 0, :2] = np.array([x, y]) - half * axis
        out[i, 1, :2] = np.array([x, y]) + half * axis
        out[i, :, 2] = mover_z[i]
        out[i, 0, 3] = yaw - roll / g.gear_a
        out[i, 1, 3] = yaw - pitch / g.gear_b
    return out


def fk_reference(movers: np.ndarray, g: PlatformGeometry = G) -> np.ndarray:
    out = np.empty((len(movers), 6))
    for i, (a, b) in enumerate(movers):
        d = np.hypot(*(b[:2] - a[:2]))
        yaw = math.atan2(b[1] - a[1], b[0] - a[0])
        theta = math.acos((0.5 * d - g.link_offset) / g.link_length)
        rel_a = (a[3] - yaw + math.pi) % (2 * math.pi) - math.pi
        rel_b = (b[3] - yaw + math.pi) % (2 * math.pi) - math.pi
        out[i] = [*(0.5 * (a[:2] + b[:2])), 0.5 * (a[2] + b[2]) + g.lift_offset + g.link_length * math.sin(theta),
                  -g.gear_a * rel_a, -g.gear_b * rel_b, yaw]
    return out


def test_ik_and_fk_match_the_numpy_reference_and_round_trip(rng):
    n = 500
    mz = rng.uniform(0.003, 0.02, n)
    pose = random_poses(rng, n, mz)
    movers = platform_ik(torch.as_tensor(pose), torch.as_tensor(mz))
    assert movers.dtype == torch.float64 and movers.shape == (n, 2, 4)
    np.testing.assert_allclose(movers.numpy(), ik_reference(pose, mz), rtol=0, atol=1e-12, err_msg=str(rng))
    back = platform_fk(movers)
    np.testing.assert_allclose(back.numpy(), fk_reference(movers.numpy()), rtol=0, atol=1e-12, err_msg=str(rng))
    np.testing.assert_allclose(back.numpy(), pose, rtol=0, atol=1e-6, err_msg=str(rng))
    # the movers really are as far apart as the lift needs, and within the mover distance limits
    d = np.linalg.norm(movers[:, 1, :2] - movers[:, 0, :2], axis=-1)
    assert d.min() >= G.min_mover_distance - 1e-9 and d.max() <= G.max_mover_distance + 1e-9
    # float32 (a policy's dtype) stays within float32 round-off; batch shapes are kept
    m32 = platform_ik(torch.as_tensor(pose, dtype=torch.float32).reshape(5, 100, 6),
                      torch.as_tensor(mz).float().reshape(5, 100))
    assert m32.shape == (5, 100, 2, 4)
    np.testing.assert_allclose(platform_fk(m32).reshape(n, 6).numpy(), pose, rtol=0, atol=2e-4, err_msg=str(rng))


def test_ik_equals_magbotsim_platform_ik(rng):
    sixd = pytest.importorskip("magbotsim.magbots.sixD_platform")
    n = 200
    mz = rng.uniform(0.003, 0.02, n)
    pose = random_poses(rng, n, mz)
    ref = sixd.SixDPlatformMagBotsAPM4330(1, np.array([0]), np.array([1]))
    want = ref.platformSetPose2MoverSetPose(pose.copy(), mover_z_d=mz.copy(), use_euler=True)  # [n, 2, (xyz, rpy)]
    got = platform_ik(torch.as_tensor(pose), torch.as_tensor(mz)).numpy()
    np.testing.assert_allclose(got, want[:, :, [0, 1, 2, 5]], rtol=0, atol=1e-12, err_msg=str(rng))
    np.testing.assert_allclose(want[:, :, 3:5], 0.0)  # MagBotSim's movers stay level too


@pytest.mark.parametrize(
    "index, value, limit",
    [(3, 0.3, "roll"), (4, -0.3, "pitch"), (2, 0.5, "height_max"), (2, 0.15, "height_min"),
     (0, float("nan"), "non_finite")],
)
def test_limits_are_named_and_nothing_is_clamped(rng, index, value, limit):
    mz = np.full(8, 0.01)
    pose = random_poses(rng, 8, mz)
    pose[5, index] = value
    t = torch.as_tensor(pose)
    viol = platform_limit_violations(t, 0.01)
    assert viol[limit].tolist() == [i == 5 for i in range(8)], str(rng)
    for other, mask in viol.items():
        if other != limit and not (limit == "non_finite"):
            assert not mask.any(), (other, str(rng))
    with pytest.raises(MagBotLimitError, match=f"index \\(5,\\) violates limit '{limit}'"):
        platform_ik(t, 0.01)
    with pytest.raises(MagBotLimitError, match=limit):
        check_platform_pose(t, 0.01)
    if limit in ("roll", "pitch"):  # unchecked IK maps the pose as asked: FK gives it back, no clamping
        back = platform_fk(platform_ik(t, 0.01, check=False))
        assert float(back[5, index]) == pytest.approx(value, abs=1e-9)


def test_height_range_follows_the_distance_limits():
    lo, hi = G.height_range
    for d, h in ((G.max_mover_distance, lo), (G.min_mover_distance, hi)):
        pose = torch.tensor([[0.5, 0.5, 0.01 + h, 0.0, 0.0, 0.3]], dtype=torch.float64)
        m = platform_ik(pose, 0.01)
        assert float(torch.linalg.norm(m[0, 1, :2] - m[0, 0, :2])) == pytest.approx(d, abs=1e-9)


def test_bad_inputs_and_geometry_raise_clear_errors():
    with pytest.raises(MagBotLimitError, match=r"shape \[\.\.\., 6\]"):
        platform_ik(torch.zeros(3, 5), 0.01)
    with pytest.raises(MagBotLimitError, match="floating-point"):
        platform_ik(torch.zeros(3, 6, dtype=torch.int64), 0.01)
    with pytest.raises(MagBotLimitError, match="broadcast"):
        platform_ik(torch.zeros(3, 6), torch.zeros(4), check=False)
    with pytest.raises(MagBotLimitError, match=r"shape \[\.\.\., 2, 4\]"):
        platform_fk(torch.zeros(3, 2, 3))
    with pytest.raises(MagBotLimitError, match="link_length"):
        PlatformGeometry(link_length=-1.0)
    with pytest.raises(MagBotLimitError, match="reach"):
        PlatformGeometry(max_mover_distance=0.6)
    with pytest.raises(MagBotLimitError, match="min_mover_distance"):
        PlatformGeometry(min_mover_distance=0.5)
    with pytest.raises(MagBotLimitError, match="gear_a"):
        PlatformGeometry(gear_a=0.05)
