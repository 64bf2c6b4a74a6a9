"""Device-side task math for pushing: exact coverage vs shapely, obstacle contact flags from mujoco-warp contacts."""

import mujoco
import numpy as np
import pytest
import torch
import warp as wp

from magwarp.layout import Layout
from magwarp.mjcf import OBJECT_SHAPES, ObjectSpec, ObstacleSpec, generate_mjcf
from magwarp.physics import ContactFlags, ControlParams, MjwBackend, coverage

shapely = pytest.importorskip("shapely")
import shapely.affinity as sa  # noqa: E402
import shapely.geometry as sg  # noqa: E402

wp.config.quiet = True


def _shapely_poly(obj: ObjectSpec, pose):
    if obj.shape == "cylinder":
        base = sg.Point(0, 0).buffer(obj.radius, quad_segs=512)
    else:
        base = shapely.union_all([sg.box(cx - hx, cy - hy, cx + hx, cy + hy) for cx, cy, hx, hy in obj.rects()])
    return sa.translate(sa.rotate(base, pose[2], origin=(0, 0), use_radians=True), pose[0], pose[1])


@pytest.mark.parametrize("shape", OBJECT_SHAPES)
def test_coverage_matches_shapely_on_random_poses(shape, rng):
    obj = ObjectSpec(shape, width=rng.uniform(0.04, 0.08), height=rng.uniform(0.04, 0.08), segment_width=0.015,
                     radius=rng.uniform(0.03, 0.06))
    n = 300
    goal = np.c_[rng.uniform(0.2, 0.5, (n, 2)), rng.uniform(-np.pi, np.pi, n)]
    ach = goal + np.c_[rng.normal(0, 0.03, (n, 2)), rng.normal(0, 0.8, n)]
    ach[:20] = goal[:20]  # full coverage
    ach[20:40, 0] += 0.5  # disjoint
    got = coverage(torch.tensor(ach), torch.tensor(goal), obj).numpy()
    want = np.array([_shapely_poly(obj, a).intersection(_shapely_poly(obj, g)).area / _shapely_poly(obj, g).area
                     for a, g in zip(ach, goal)])
    # float32 clipping: exact to ~1e-6; the disc reference is a 2048-gon (area deficit ~2e-6 relative)
    tol = 1e-5 if shape == "cylinder" else 2e-6
    assert np.abs(got - want).max() < tol, f"{rng}: max error {np.abs(got - want).max():.3g}"
    assert np.all(got[:20] > 1 - 1e-5) and np.all(got[20:40] == 0)
    assert 0.05 < np.median(got[40:]) < 0.95  # the random poses exercise partial overlaps


def test_coverage_accepts_sin_cos_goals_and_batch_shapes():
    obj = ObjectSpec("T")
    yaw_a, yaw_g = torch.tensor([[0.3, 1.0]]), torch.tensor([[0.5, -2.0]])
    a3 = torch.stack([torch.full_like(yaw_a, 0.3), torch.full_like(yaw_a, 0.31), yaw_a], -1)
    g3 = torch.stack([torch.full_like(yaw_g, 0.3), torch.full_like(yaw_g, 0.3), yaw_g], -1)
    a4 = torch.cat([a3[..., :2], torch.sin(a3[..., 2:]), torch.cos(a3[..., 2:])], -1)
    g4 = torch.cat([g3[..., :2], torch.sin(g3[..., 2:]), torch.cos(g3[..., 2:])], -1)
    c3, c4 = coverage(a3, g3, obj), coverage(a4, g4, obj)
    assert c3.shape == (1, 2)
    torch.testing.assert_close(c3, c4, atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="last dimension"):
        coverage(torch.zeros(3, 5), torch.zeros(3, 5), obj)


def test_obstacle_contact_flags_per_world():
    xml = generate_mjcf(Layout.grid(3, 3), 1, mover_xy=[[0.12, 0.36]], objects=[ObjectSpec()], object_xy=[[0.6, 0.12]],
                        obstacles=[ObstacleSpec((0.34, 0.36), (0.03, 0.1, 0.03)), ObstacleSpec((0.6, 0.4), (0.03, 0.1, 0.03))])
    b = MjwBackend(xml, 3, control=ControlParams(num_cycles=20), device="cpu")
    flags = ContactFlags(b, {"mover": ["mover_geom_"], "object": ["object_0_geom_"], "obstacle": ["obstacle_geom_"]},
                         [("mover", "obstacle"), ("object", "obstacle")])
    b.init_object_qpos[:, 0, 2] = 0.0199
    b.init_object_qpos[2, 0, :2] = torch.tensor([0.6, 0.245])  # world 2: box 5 mm inside obstacle 1
    b.reset()
    a = torch.zeros(3, 1, 2)
    a[0, 0, 0] = 10.0  # world 0 drives the mover into obstacle 0 (gap 0.0825 m: contact after ~0.13 s)
    a[1, 0, 0] = -10.0  # world 1 drives away
    hit_mover, hit_object = [], []
    for _ in range(10):
        flags.clear()
        b.step(a)
        hit_mover.append(flags.pair("mover", "obstacle").clone())
        hit_object.append(flags.pair("obstacle", "object").clone())
    hm, ho = torch.stack(hit_mover), torch.stack(hit_object)
    assert hm[:, 0].any() and not hm[:6, 0].any()  # contact only once the mover reaches it
    assert not hm[:, 1].any() and not hm[:, 2].any()
    assert ho[0, 2] and not ho[:, 0].any() and not ho[:, 1].any()
    assert b.object_qpos[2, 0, 1] < 0.2405  # and the contact pushed the box out
    # the mover really is at the obstacle when flagged
    first = int(torch.nonzero(hm[:, 0])[0])
    assert first >= 6
    assert b.mover_qpos[0, 0, 0] + 0.0775 > 0.31 - 1e-3


@pytest.mark.parametrize("shape", ["circle", "box"])
def test_mover_checks_match_numpy_reference(shape, rng):
    from magwarp import reference
    from magwarp.layout import MoverSpec
    from magwarp.physics.mover_checks import MoverChecks

    tiles = np.ones((6, 5), dtype=np.int32)
    tiles[2, 2] = tiles[4, 0] = 0
    layout = Layout(tiles)
    mover = MoverSpec(collision_shape=shape, wall_margin=0.01, margin=0.005)
    W, M = 64, 2
    b = MjwBackend(generate_mjcf(layout, M, mover), W, device="cpu")
    checks = MoverChecks(b, layout, mover)
    xy = rng.uniform(0.05, np.array(layout.extent) - 0.05, (W, M, 2))
    xy[:, 1] = xy[:, 0] + rng.normal(0, 0.12, (W, 2))  # near pairs
    yaw = rng.uniform(-np.pi, np.pi, (W, M))
    tilt = rng.normal(0, 0.02, (W, M, 2))  # small roll/pitch: the check uses the heading only
    q = np.zeros((W, M, 4))
    for w in range(W):
        for k in range(M):
            r = np.array([np.cos(tilt[w, k, 0] / 2), np.sin(tilt[w, k, 0] / 2), 0, 0])
            z = np.array([np.cos(yaw[w, k] / 2), 0, 0, np.sin(yaw[w, k] / 2)])
            out = np.zeros(4)
            mujoco.mju_mulQuat(out, z, r)
            q[w, k] = out
    b.mover_qpos[..., :2] = torch.as_tensor(xy, dtype=torch.float32)
    b.mover_qpos[..., 3:] = torch.as_tensor(q, dtype=torch.float32)
    checks.clear()
    checks._launch()
    wall = reference.wall_collisions(layout, mover, xy, yaw).any(axis=1)
    pairs = np.array([len(reference.mover_collision_pairs(mover, xy[w], yaw[w])) > 0 for w in range(W)])
    # float32 positions: skip configurations within 1e-5 m of a decision boundary
    got_wall, got_pair = checks.wall_collision.numpy(), checks.mover_collision.numpy()
    assert (got_wall != wall).sum() <= 1 and (got_pair != pairs).sum() <= 1, rng
    assert wall.any() and (~wall).any() and pairs.any() and (~pairs).any()


@pytest.mark.parametrize("rotation", [False, True])
def test_control_kernel_matches_numpy_law_on_random_states(rng, rotation):
    from magwarp.physics import oracle

    W, M = 16, 2
    for jerk in (False, True):
        # with rotation: a third (yaw) command, a position limit of 0.8 rad that some movers are near
        control = ControlParams(jerk=jerk, rotation=rotation, p_max_c=0.8 if rotation else None)
        b = MjwBackend(generate_mjcf(Layout.grid(3, 3), M), W, control=control, device="cpu", use_graph=False)
        mjm, mjd = b.mjm, mujoco.MjData(b.mjm)
        qpos = np.tile(mjm.qpos0, (W, 1))
        qvel = rng.normal(0, 1.0, (W, mjm.nv))
        for w in range(W):
            for k in range(M):
                qa = b.mover_qadr[k]
                qpos[w, qa + 2] += rng.normal(0, 0.003)
                quat = rng.normal(0, 1, 4) * [1, 0.1, 0.1, 1]  # tilts up to ~0.2 rad and any heading
                qpos[w, qa + 3: qa + 7] = quat / np.linalg.norm(quat)
        qvel[:, b.mover_dadr[0]:b.mover_dadr[0] + 2] *= 2.5  # some movers above v_max
        cmd = rng.normal(0, 80 if jerk else 8, (W, M, 3))
        cmd[..., 2] *= 30  # yaw commands span the +-122 rad/s^2 (+-611 rad/s^3) limits
        acc0 = rng.normal(0, 6, (W, M, 2))
        acc_c0 = rng.normal(0, 40, (W, M))
        # the kernel reads float32: the float64 oracle gets the same rounded inputs
        qpos, qvel, cmd, acc0, acc_c0 = (np.float64(np.float32(x)) for x in (qpos, qvel, cmd, acc0, acc_c0))
        b.qpos_t.copy_(torch.as_tensor(qpos)), b.qvel_t.copy_(torch.as_tensor(qvel))
        b.cmd_t.copy_(torch.as_tensor(cmd[..., :2])), b.acc_t.copy_(torch.as_tensor(acc0))
        b.cmd_c_t.copy_(torch.as_tensor(cmd[..., 2])), b.acc_c_t.copy_(torch.as_tensor(acc_c0))
        c = b.control
        b.apply_control()
        got = b.data.qfrc_applied.numpy()
        # Above v_max the law brakes within one cycle, a = (v_limited - v) / dt: in float32 the difference keeps about
        # one ulp of |v|, so the planar force may differ by mass * ulp(|v|) / dt (~4e-4 N at 3 m/s), 4 ulps allowed.
        mass = mjm.body_mass[b.mover_body]
        dt = mjm.opt.timestep
        for w in range(W):
            acc_slack = np.array([4 * np.finfo(np.float32).eps * (np.abs(qvel[w, d:d + 2]).max() + c.a_max * dt) / dt
                                  for d in b.mover_dadr])  # (M,) m/s^2
            slack = np.zeros(mjm.nv)
            for k, d in enumerate(b.mover_dadr):
                slack[d:d + 2] = acc_slack[k] * mass[k]
            mjd.qpos[:], mjd.qvel[:] = qpos[w], qvel[w]
            acc = acc0[w].copy()
            yaw_state = np.zeros((M, 3))
            yaw_state[:, 0] = acc_c0[w]
            oracle.control_forces(mjm, mjd, b.mover_body, b.mover_qadr, b.mover_dadr, b.hover_z,
                                  cmd[w] if rotation else cmd[w, :, :2], acc, c, yaw_state)
            err = np.abs(got[w] - mjd.qfrc_applied)
            bound = 2e-5 + 2e-4 * np.abs(mjd.qfrc_applied) + slack
            assert (err <= bound).all(), f"{rng} jerk={jerk} w={w}: {err} > {bound}"
            acc_err = np.abs(b.acc_t[w].numpy() - acc)
            acc_bound = 1e-4 + 1e-4 * np.abs(acc) + acc_slack[:, None]
            assert (acc_err <= acc_bound).all(), f"{rng} jerk={jerk} w={w}: {acc_err} > {acc_bound}"
            if rotation:
                np.testing.assert_allclose(b.acc_c_t[w].numpy(), yaw_state[:, 0], rtol=1e-4, atol=2e-3, err_msg=str(rng))
    if rotation:  # the position limit engaged somewhere: some yaw accelerations were cut below the command
        assert (np.abs(b.acc_c_t.numpy()) < np.minimum(np.abs(cmd[..., 2]), 122.17) - 1).any()
