"""MJCF generation: loads in MuJoCo for holes and every object shape, contact filtering, hooks, linear cost."""

import re

import mujoco
import numpy as np

import pytest

from magwarp.layout import Layout, LayoutError, MoverSpec, benchmark_layout
from magwarp.mjcf import OBJECT_SHAPES, ObjectSpec, ObstacleSpec, XmlHooks, generate_mjcf, tile_rectangles

HOLES = Layout(np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]))


def _geom_area(m: mujoco.MjModel, body: int) -> float:
    area = 0.0
    for g in range(m.ngeom):
        if m.geom_bodyid[g] == body:
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
                area += 4 * m.geom_size[g, 0] * m.geom_size[g, 1]
            else:
                area += np.pi * m.geom_size[g, 0] ** 2
    return area


@pytest.mark.parametrize("shape", OBJECT_SHAPES)
def test_every_shape_loads_on_layout_with_holes(shape):
    obj = ObjectSpec(shape, mass=0.3)
    xml = generate_mjcf(HOLES, 3, objects=[obj], object_xy=[[0.12, 0.60]], object_yaw=[0.3], goal_markers=True,
                        goal_xy=[[0.6, 0.6]], obstacles=[ObstacleSpec((0.84, 0.5))])
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    body = m.body("object_0").id
    assert m.body_subtreemass[body] == pytest.approx(0.3)
    assert _geom_area(m, body) == pytest.approx(obj.area, rel=1e-9)
    # movers at the centres of the first three present tiles (the hole at (1, 1) is skipped), object pose as asked
    np.testing.assert_allclose(d.qpos[[0, 1, 7, 8, 14, 15]], [0.12, 0.12, 0.12, 0.36, 0.12, 0.60], atol=1e-9)
    q = d.qpos[21:28]
    assert q[:2] == pytest.approx([0.12, 0.60])
    assert 2 * np.arctan2(q[6], q[3]) == pytest.approx(0.3)
    assert m.nmocap == 1 and d.mocap_pos[0, :2] == pytest.approx([0.6, 0.6])
    # tiles: one visual geom per present tile; collision support covers exactly the present tiles
    names = [m.geom(g).name for g in range(m.ngeom)]
    assert sum(n.startswith("tile_") and not n.startswith("tile_support") for n in names) == HOLES.num_tiles
    assert "tile_1_1" not in names


def test_object_parts_match_magbotsim_definition():
    # T: stem (s, h) at the origin + two bars (w - s)/2 long at y = h - s; L: one bar at y = -(h - s); X: bars at y = 0
    w, h, s = 0.06, 0.06, 0.02
    t = ObjectSpec("T").rects()
    np.testing.assert_allclose(t, [[0, 0, s, h], [-(0.02 + s), h - s, 0.02, s], [0.02 + s, h - s, 0.02, s]])
    assert ObjectSpec("L").rects()[1].tolist() == pytest.approx([0.04, -(h - s), 0.02, s])
    assert ObjectSpec("X").rects()[1:, 1].tolist() == [0.0, 0.0]
    # outer extent of the bars equals the half-width
    assert np.max(np.abs(t[:, 0]) + t[:, 2]) == pytest.approx(w)


def test_contact_bits_exclude_mover_mover_and_mover_tile_but_not_objects():
    xml = generate_mjcf(Layout.grid(2, 2), 2, mover_xy=[[0.2, 0.24], [0.3, 0.24]], objects=[ObjectSpec()],
                        object_xy=[[0.24, 0.40]], tile_collision="tiles")
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    # overlap the movers with each other, sink them into the tiles, and push the object into mover 1
    d.qpos[2] = d.qpos[9] = -0.001
    d.qpos[14:16] = [0.3, 0.24 + 0.0775 + 0.055]
    mujoco.mj_forward(m, d)
    pairs = {tuple(sorted((m.geom(d.contact.geom[i][0]).name, m.geom(d.contact.geom[i][1]).name))) for i in range(d.ncon)}
    assert not any(a.startswith("mover") and b.startswith("mover") for a, b in pairs)
    assert not any(("mover" in a and "tile" in b) or ("tile" in a and "mover" in b) for a, b in pairs)
    assert ("mover_geom_1", "object_0_geom_0") in pairs
    assert any(a.startswith("object_0") and b.startswith("tile_") for a, b in pairs)
    assert "exclude" not in xml


def test_movers_hover_with_gravity_compensation():
    m = mujoco.MjModel.from_xml_string(generate_mjcf(Layout.grid(2, 2), 2))
    d = mujoco.MjData(m)
    mujoco.mj_step(m, d, 200)
    np.testing.assert_allclose(d.qpos[2], MoverSpec().hover_z, atol=1e-9)


@pytest.mark.parametrize("name", ["B0", "B2", "B3", "B9"])
def test_tile_rectangles_cover_layout_exactly(name):
    layout, _ = benchmark_layout(name)
    cover = np.zeros_like(layout.tiles)
    for i0, j0, ni, nj in tile_rectangles(layout.tiles):
        cover[i0:i0 + ni, j0:j0 + nj] += 1
    np.testing.assert_array_equal(cover, layout.tiles)
    assert len(tile_rectangles(Layout.grid(5, 4).tiles)) == 1


def test_merged_support_holds_objects_and_holes_drop_them():
    # object over a hole falls (merged support follows holes), object on tiles rests at its half height
    xml = generate_mjcf(HOLES, 0, objects=[ObjectSpec(), ObjectSpec()], object_xy=[[0.36, 0.36], [0.12, 0.12]])
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_step(m, d, 300)
    assert d.qpos[2] < -0.05
    assert d.qpos[9] == pytest.approx(0.02, abs=2e-4)


def test_user_hooks_add_sensor_actuator_and_mover_payload():
    hooks = XmlHooks(
        assets='<material name="user_mat" rgba="0 1 0 1"/>',
        defaults='<default class="user"><geom rgba="0 0 1 1"/></default>',
        worldbody='<body name="ball" pos="0.24 0.24 0.1"><freejoint/><geom class="user" type="sphere" size="0.02"/></body>',
        actuator='<motor name="push" joint="mover_joint_0" gear="1 0 0 0 0 0"/>',
        sensor='<framepos name="ball_pos" objtype="body" objname="ball"/>',
        contact='<exclude body1="ball" body2="mover_1"/>',
        mover_bodies=['<geom name="payload" type="box" size="0.01 0.01 0.01" pos="0 0 0.02" mass="0.1"/>', None],
    )
    m = mujoco.MjModel.from_xml_string(generate_mjcf(Layout.grid(2, 2), 2, hooks=hooks))
    assert m.nu == 1 and m.nsensor == 1 and m.body("ball").id > 0
    assert m.body_subtreemass[m.body("mover_0").id] == pytest.approx(1.34)
    # dict form with MagBotSim-like keys is accepted; unknown keys are named
    generate_mjcf(Layout.grid(2, 2), 1, hooks={"sensor": '<framepos objtype="body" objname="mover_0"/>'})
    with pytest.raises(LayoutError, match="bogus"):
        generate_mjcf(Layout.grid(2, 2), 1, hooks={"bogus": ""})


def test_bad_inputs_name_the_value():
    with pytest.raises(LayoutError, match="hexagon"):
        ObjectSpec("hexagon")
    with pytest.raises(LayoutError, match="segment_width"):
        ObjectSpec("T", width=0.02, segment_width=0.03)
    with pytest.raises(LayoutError, match=r"mover_xy must have shape \(2, 2\)"):
        generate_mjcf(Layout.grid(2, 2), 2, mover_xy=[[0.1, 0.1]])
    with pytest.raises(LayoutError, match="tile_collision"):
        generate_mjcf(Layout.grid(2, 2), 1, tile_collision="mesh")
    with pytest.raises(LayoutError, match="num_movers=5"):
        generate_mjcf(Layout.grid(2, 2), 5)


def test_generation_is_linear_in_movers():
    # No wall-clock asserts: the output (and the single pass that writes it) grows by a constant per mover, and no
    # pairwise section (MagBotSim's O(N^2) <exclude> list) appears.
    layout = Layout.grid(64, 64)
    xy = layout.default_starts(2000)
    sizes = [len(generate_mjcf(layout, n, mover_xy=xy[:n])) for n in (0, 500, 1000, 2000)]
    per_mover = np.diff(sizes) / np.diff([0, 500, 1000, 2000])
    assert np.ptp(per_mover) < 0.05 * per_mover.mean(), per_mover
    xml = generate_mjcf(Layout.grid(40, 25), 1000)
    assert xml.count("<freejoint") == 1000 and "<exclude" not in xml and "<contact>" not in xml
    m = mujoco.MjModel.from_xml_string(xml)
    assert m.nbody == 1001 and m.nexclude == 0


@pytest.mark.parametrize("field, value", [("depth", 1.18e21), ("width", 11.0), ("mass", 2e4)])
def test_object_sizes_and_mass_are_bounded(field, value):
    """An object past a planar motor's scale is refused with its name and value (object_depth=1.18e21 overflowed the
    float32 physics into NaN observations)."""
    with pytest.raises(LayoutError, match=rf"ObjectSpec\.{field} must be at most .*{re.escape(repr(value))}"):
        ObjectSpec(**{field: value})
