"""Device-side task math for pushing: exact coverage vs shapely, obstacle contact flags from mujoco-warp contacts."""

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
