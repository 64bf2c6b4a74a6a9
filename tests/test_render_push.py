"""Top-down rendering of the push envs: object, object goal, obstacles and movers, one world or a mosaic."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

import magwarp  # noqa: F401 - registers the ids
from magwarp.envs.push import PushTEnv
from magwarp.envs.push_obstacles import PushWithObstaclesEnv
from magwarp.render import colors


def _park_movers(env, xy=(0.06, 0.06)):
    """Put every mover of every world at ``xy`` (a corner), out of the way of the object and its goal."""
    q = env.backend.mover_qpos
    q[..., 0] = xy[0]
    q[..., 1] = xy[1]


def _set_object(env, world, x, y, yaw):
    q = env.backend.object_qpos
    q[world, 0, 0], q[world, 0, 1] = x, y
    q[world, 0, 3], q[world, 0, 4], q[world, 0, 5], q[world, 0, 6] = math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)


def _inside_parts(x, y, pose, parts, pad):
    """Pixel centres ``x, y`` (world m) inside the union of ``parts`` at ``pose`` grown by ``pad`` (m, may be < 0)."""
    px, py, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = x - px, y - py
    bx, by = c * dx + s * dy, -s * dx + c * dy  # body frame
    out = np.zeros(x.shape, dtype=bool)
    for cx, cy, hx, hy in parts:
        out |= (np.abs(bx - cx) <= hx + pad) & (np.abs(by - cy) <= hy + pad)
    return out


def _pixel_world_xy(renderer, cell=0):
    r0, c0 = renderer.cell_origin(cell)
    rows, cols = np.meshgrid(np.arange(renderer.cell_h), np.arange(renderer.cell_w), indexing="ij")
    return (cols + 0.5) / renderer.px_per_m, (renderer.cell_h - rows - 0.5) / renderer.px_per_m, (rows + r0, cols + c0)


def _is_object_colour(img):
    fill = np.all(np.abs(img.astype(int) - colors.OBJECT) <= 2, axis=-1)
    edge = np.all(np.abs(img.astype(int) - colors.OBJECT_EDGE) <= 2, axis=-1)
    return fill | edge


@pytest.fixture(scope="module")
def push_t():
    env = PushTEnv(num_envs=4, device="cpu", render_mode="rgb_array", seed=3)
    env.reset(seed=3)
    return env


def test_frame_shape_dtype_and_mosaic(push_t):
    push_t.set_render_worlds(4)
    img = push_t.render()
    assert isinstance(img, np.ndarray) and img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    r = push_t._renderer
    assert img.shape == r.shape and r.num_cells == 4 and r.rows == 2 and r.cols == 2
    push_t.set_render_worlds([2])
    one = push_t.render()
    assert one.shape == push_t._renderer.shape and one.shape[0] < img.shape[0] * 2


@pytest.mark.parametrize("yaw", [0.0, 0.7, math.pi / 2])
def test_object_covers_the_expected_pixels_at_a_known_pose(push_t, yaw):
    env = push_t
    env.set_render_worlds([1])
    _park_movers(env)
    env.goal_xy[:] = torch.tensor([0.84, 0.60])  # far corner, away from the object
    pose = (0.50, 0.36, yaw)
    _set_object(env, 1, *pose)
    img = env.render()
    r = env._renderer
    x, y, (rows, cols) = _pixel_world_xy(r)
    obj = _is_object_colour(img[rows, cols])
    parts = env.object_parts()
    assert len(parts) == 3  # the T: stem and two half bars (ObjectSpec.rects)
    px = 1.0 / r.px_per_m
    inner = _inside_parts(x, y, pose, parts, -1.5 * px)
    outer = _inside_parts(x, y, pose, parts, 1.5 * px)
    assert inner.sum() > 50
    assert obj[inner].all(), f"{(~obj[inner]).sum()} pixels inside the T are not drawn as object (yaw={yaw})"
    assert not obj[~outer].any(), f"{obj[~outer].sum()} pixels outside the T are drawn as object (yaw={yaw})"
    # area check: the drawn object is the T's area (ObjectSpec.area) within a pixel-wide rim
    area_px = env.object.area * r.px_per_m**2
    assert inner.sum() <= obj.sum() <= outer.sum()
    assert abs(obj.sum() - area_px) < 0.25 * area_px


def test_goal_is_drawn_at_the_goal_pose(push_t):
    env = push_t
    env.set_render_worlds([0])
    _park_movers(env)
    _set_object(env, 0, 0.25, 0.50, 0.0)
    env.goal_xy[0] = torch.tensor([0.70, 0.30])
    env.goal_yaw[0] = 0.3
    img = env.render()
    r = env._renderer
    x, y, (rows, cols) = _pixel_world_xy(r)
    inner = _inside_parts(x, y, (0.70, 0.30, 0.3), env.object_parts(), -2.0 / r.px_per_m)
    tile = np.asarray(colors.TILE)
    goal_px = img[rows, cols][inner].astype(int)
    # translucent green over the tiles: greener than the tile, and not the object's colour
    assert (goal_px[:, 1] - goal_px[:, 0]).mean() > 20 and not _is_object_colour(goal_px[None])[0].any()
    assert np.abs(goal_px - tile).sum(-1).mean() > 30


def test_frames_change_when_the_object_moves(push_t):
    env = push_t
    env.set_render_worlds(4)
    _park_movers(env)
    _set_object(env, 2, 0.40, 0.36, 0.0)
    a = env.render()
    _set_object(env, 2, 0.55, 0.36, 0.5)
    b = env.render()
    changed = np.any(a != b, axis=-1)
    assert changed.any()
    # only cell 2 (row 1, col 0) changed
    r = env._renderer
    r0, c0 = r.cell_origin(2)
    outside = changed.copy()
    outside[r0:r0 + r.cell_h, c0:c0 + r.cell_w] = False
    assert not outside.any()


def test_frames_change_when_the_env_steps():
    env = gym.make_vec("magwarp/PushBox-v0", num_envs=2, device="cpu", render_mode="rgb_array")
    env.reset(seed=0)
    env.set_render_worlds(2)
    before = env.render()
    action = torch.full((2, 2), 5.0)
    for _ in range(3):
        env.step(action)
    after = env.render()
    assert before.shape == after.shape and np.any(before != after)


def test_obstacles_are_drawn():
    env = PushWithObstaclesEnv(num_envs=1, device="cpu", render_mode="rgb_array", seed=0)
    img = env.render()
    r = env._renderer
    x, y, (rows, cols) = _pixel_world_xy(r)
    fill = np.all(np.abs(img[rows, cols].astype(int) - colors.OBSTACLE) <= 2, axis=-1)
    edge = np.all(np.abs(img[rows, cols].astype(int) - colors.OBSTACLE_EDGE) <= 2, axis=-1)
    drawn = fill | edge
    pad = 1.5 / r.px_per_m
    inner = np.zeros_like(drawn)
    for o in env.obstacles:
        inner |= (np.abs(x - o.xy[0]) <= o.half_size[0] - pad) & (np.abs(y - o.xy[1]) <= o.half_size[1] - pad)
    assert inner.sum() > 20 and drawn[inner].all()
    s = env.render_state()
    assert s["obstacles"].shape == (1, 2, 5)  # per world: [W, K, 5]


def test_render_mode_none_and_bad_mode():
    env = PushTEnv(num_envs=1, device="cpu", seed=0)
    assert env.render() is None
    with pytest.raises(ValueError, match="render_mode"):
        PushTEnv(num_envs=1, device="cpu", render_mode="human")


def test_cli_render_and_view_push_env(capsys, tmp_path):
    import imageio.v3 as iio

    from magwarp import cli

    gif, png = str(tmp_path / "push.gif"), str(tmp_path / "push.png")
    rc = cli.main(["render", "magwarp/PushT-v0", "--worlds", "2", "--steps", "3", "--device", "cpu",
                   "-o", gif, "-o", png])
    out, err = capsys.readouterr()
    assert rc == 0, err
    frames = iio.imread(gif)
    assert frames.shape[0] == 3 and iio.imread(png).shape == frames.shape[1:]
    pytest.importorskip("newton")
    pytest.importorskip("pxr")
    usd = str(tmp_path / "push.usda")
    rc = cli.main(["view", "magwarp/PushWithObstacles-v0", "--worlds", "2", "--steps", "3", "--device", "cpu",
                   "--viewer", "usd", "-o", usd])
    out, err = capsys.readouterr()
    assert rc == 0, err
    text = open(usd).read()
    assert "objects" in text and "object_goals" in text and "obstacles" in text


def test_each_world_draws_its_own_object_variant():
    env = PushTEnv(num_envs=2, device="cpu", render_mode="rgb_array", seed=0,
                   object_ranges={"width": (0.05, 0.09), "height": (0.05, 0.09)}, object_variants=8)
    env.reset(seed=0)
    env.object_variant.copy_(torch.tensor([0, 1], dtype=torch.int32))
    _park_movers(env)
    for w in range(2):
        _set_object(env, w, 0.36, 0.40, 0.3)
    env.goal_xy[:] = torch.tensor([0.1, 0.65])  # goals out of the way
    img = env.render()
    r = env._renderer
    for w in range(2):
        x, y, (rows, cols) = _pixel_world_xy(r, w)
        drawn = _is_object_colour(img[rows, cols])
        parts = env.object_parts(w)
        pad = 1.5 / r.px_per_m
        assert drawn[_inside_parts(x, y, (0.36, 0.40, 0.3), parts, -pad)].all()
        assert not drawn[~_inside_parts(x, y, (0.36, 0.40, 0.3), parts, pad)].any()
    assert env.object_parts(0) != env.object_parts(1)


def test_bad_object_shape_index_names_the_value():
    env = PushTEnv(num_envs=2, device="cpu", render_mode="rgb_array", seed=0)
    env.render()
    s = env.render_state()
    with pytest.raises(ValueError, match="got values from 0 to 3"):
        env._renderer.draw(s["pos"], s["yaw"], object_poses=s["object_poses"], object_shape=torch.tensor([0, 3]))
