"""Top-down views of big swarms: image sizes of the whole-world view, zoomed windows that show exactly the movers
inside them (pixel colours at known positions, and the same pixels as the whole view), dots of at least 2 x 2
pixels coloured by state for a 1000-mover world, and ``magwarp render magwarp/Swarm-v0`` end to end."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp import cli
from magwarp.layout import Layout, MoverSpec
from magwarp.render import TopDownRenderer, colors
from magwarp.render.swarm import fit_px_per_tile, mover_states
from magwarp.swarm import SwarmEnv

STATES = np.asarray(colors.STATE_PALETTE, dtype=np.uint8)


def _pixel(img, renderer, xy):
    r, c = renderer.world_to_pixel(np.asarray(xy, dtype=np.float64))
    return img[int(r), int(c)]


def test_whole_world_view_size():
    env = SwarmEnv(1, num_movers=64, device="cpu", seed=0, render_mode="rgb_array")  # a 16 x 16 layout
    assert env.layout.shape == (16, 16)
    assert env.render().shape == (16 * 48, 16 * 48, 3)  # fits 1024 px at the most detailed 48 px per tile
    env.set_render_view(max_image_px=256)
    assert env.render().shape == (256, 256, 3)
    env.set_render_view(px_per_tile=5)
    assert env.render().shape == (80, 80, 3)
    with pytest.raises(ValueError, match="max_image_px must be an integer >= 16"):
        env.set_render_view(max_image_px=8)
    with pytest.raises(ValueError, match="lies outside the layout"):
        env.set_render_view(window=(10.0, 10.0, 1.0, 1.0))
    assert fit_px_per_tile(Layout.grid(64, 32), 4, max_image_px=1024) == 8  # 2 x 2 worlds of 64 tiles across


def test_zoom_window_shows_only_the_movers_inside():
    layout = Layout.grid(10, 10)  # 2.4 m x 2.4 m
    window = (0.72, 0.72, 0.96, 0.96)  # [0.24, 1.2] m in x and y
    kw = dict(px_per_tile=48, heading=False, border_px=0, device="cpu")
    zoom = TopDownRenderer(layout, MoverSpec(), window=window, **kw)
    whole = TopDownRenderer(layout, MoverSpec(), **kw)
    assert zoom.shape == (192, 192, 3) and whole.shape == (480, 480, 3)
    pos = torch.tensor([[[0.60, 0.60], [2.00, 2.00], [1.00, 0.45], [1.80, 0.60]]])
    state = torch.tensor([[0, 2, 3, 4]], dtype=torch.int32)
    img = zoom.draw_numpy(pos, state=state)
    ref = whole.draw_numpy(pos, state=state)
    # inside the window: movers 0 and 2, in their state colours, at their positions
    for m in (0, 2):
        xy = pos[0, m].numpy() + np.array([-0.03, 0.03])  # off the centre: clear of the rim
        np.testing.assert_array_equal(_pixel(img, zoom, xy), STATES[state[0, m]])
        np.testing.assert_array_equal(_pixel(ref, whole, xy), STATES[state[0, m]])
    # outside it: movers 1 and 3 are drawn in the whole view, and no pixel of the window has their colours
    for m in (1, 3):
        np.testing.assert_array_equal(_pixel(ref, whole, pos[0, m].numpy() + 0.03), STATES[state[0, m]])
        assert not np.all(img == STATES[state[0, m]], axis=-1).any()
    # the window is the same pixels as that part of the whole view (rows run down from y = 1.2 m)
    crop = ref[480 - 240:480 - 48, 48:240]
    assert np.any(img != ref[:192, :192])
    assert np.all(img == crop, axis=-1).mean() > 0.999


def test_a_1000_mover_world_renders_as_state_coloured_dots():
    env = SwarmEnv(1, num_movers=1000, device="cpu", seed=1, render_mode="rgb_array")
    env.set_render_view(max_image_px=256)  # 64 tiles at 4 px: movers of 2.6 px, drawn as dots
    img = env.render()
    assert img.shape == (256, 256, 3)
    r = env._renderer
    centres = r.world_to_pixel(env.sim.pos[0, :, :2].numpy()).astype(int)
    seen = img[centres[:, 0].clip(0, 255), centres[:, 1].clip(0, 255)]
    is_state = (seen[:, None, :] == STATES[None]).all(-1).any(-1)
    assert is_state.all()
    # fresh from a reset: every mover stands still away from its goal (idle) or on it (moving colour)
    assert (seen == STATES[1]).all(-1).mean() > 0.9
    # a dot is at least 2 x 2 pixels: at least 4 state-coloured pixels in the 3 x 3 block around each centre
    inner = (centres >= 1).all(1) & (centres <= 254).all(1)
    block = np.stack([img[centres[inner, 0] + i, centres[inner, 1] + j] for i in (-1, 0, 1) for j in (-1, 0, 1)], 1)
    coloured = (block[:, :, None, :] == STATES[None, None]).all(-1).any(-1).sum(1)
    assert inner.sum() > 900 and coloured.min() >= 4


def test_mover_states():
    z = torch.zeros(1, 5, 2)
    vel = torch.tensor([[[1.0, 0], [0, 0], [0, 0], [0, 0], [0, 0]]])
    goals = torch.tensor([[[1.0, 1], [1, 1], [0, 0], [1, 1], [1, 1]]])
    collided = torch.tensor([[False, False, False, True, True]])
    carrying = torch.tensor([[True, False, False, False, True]])
    waiting = torch.tensor([[False, False, False, False, True]])
    got = mover_states(vel, z, goals, collided, carrying, waiting, 0.1)
    assert got.tolist() == [[3, 1, 0, 2, 4]] and got.dtype == torch.int32
    assert mover_states(vel, z, goals, collided, None, waiting, 0.1).tolist() == [[0, 1, 0, 2, 4]]


def test_render_command_end_to_end(capsys, tmp_path):
    from PIL import Image

    png, gif, zoom = tmp_path / "s.png", tmp_path / "s.gif", tmp_path / "z.png"
    rc = cli.main(["render", "magwarp/Swarm-v0", "--steps", "3", "--device", "cpu", "--env-kwargs",
                   '{"num_movers": 64}', "--max-px", "384", "-o", str(png), "-o", str(gif), "--no-legend"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert Image.open(png).size == (384, 384) and Image.open(gif).n_frames == 3
    rc = cli.main(["render", "magwarp/SwarmMaterialFlow-v0", "--steps", "1", "--device", "cpu", "--window",
                   "1.92,1.92,0.96,0.48", "--px-per-tile", "40", "-o", str(zoom)])
    out, err = capsys.readouterr()
    assert rc == 0, err
    w, h = Image.open(zoom).size
    assert w == 160 and h > 80  # the window, then the colour key below it


@pytest.mark.parametrize("argv, words", [
    (["--window", "1,1"], "--window must be CX,CY,W or CX,CY,W,H"),
    (["--window", "99,99,1"], "lies outside the layout"),
    (["--env-kwargs", '{"num_movers": -3}'], "num_movers must be an integer >= 1"),
])
def test_render_bad_options_are_one_line(capsys, tmp_path, argv, words):
    rc = cli.main(["render", "magwarp/Swarm-v0", "--steps", "1", "--device", "cpu", "-o", str(tmp_path / "x.png"),
                   *argv])
    _, err = capsys.readouterr()
    assert rc == 2 and words in err, err
    assert len(err.strip().splitlines()) == 1
