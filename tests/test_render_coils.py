"""The coil-current view (magwarp.render.coils): each coil's pixels in its layer's panel take the signed colour of its
current, holes stay dark, movers are outlined on top; envs with the magnetic model render it, others refuse."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from magnetics_helpers import coarse_model, magnetics_cache  # noqa: F401  (tests/ is on sys.path; a fixture)

from magwarp.layout import Layout, MoverSpec
from magwarp.magnetics.geometry import CoilSet
from magwarp.render import colors
from magwarp.render.coils import CoilCurrentRenderer, drive_currents

MAG = coarse_model(gap=(0.003, 0.005), z_step=0.002, yaw_steps=8)


def _expected(share) -> np.ndarray:
    """The kernel's byte for a share of the limit (round half up, as the kernel does)."""
    return np.floor(colors.current_rgb(share) + 0.5)


def _layer_of(coilset: CoilSet, k: int) -> int:
    per_layer = coilset.per_tile // len(coilset.coils.layers)
    return (k % coilset.per_tile) // per_layer


def test_colour_map_is_signed_and_matches_its_anchors():
    rgb = colors.current_rgb([-1.0, -0.5, 0.0, 0.5, 1.0, -3.0, 3.0, 0.25])
    np.testing.assert_allclose(rgb[:5], np.asarray(colors.CURRENT_ANCHORS, np.float32))
    np.testing.assert_allclose(rgb[5], rgb[0])  # beyond the limit: the end colours
    np.testing.assert_allclose(rgb[6], rgb[4])
    np.testing.assert_allclose(rgb[7], 0.5 * (rgb[2] + rgb[3]))
    assert rgb[4, 0] > rgb[4, 2] + 100 and rgb[0, 2] > rgb[0, 0] + 100  # positive red, negative blue


def test_coil_centres_take_their_currents_colour(rng):
    layout = Layout(np.array([[1, 1], [1, 0]]))  # tile (1, 1) missing
    coilset = CoilSet.build(layout)
    limit = 7.0
    worlds = [2, 0]
    r = CoilCurrentRenderer(coilset, worlds=worlds, px_per_tile=48, current_limit=limit, device="cpu")
    currents = rng.uniform(-limit, limit, (3, coilset.num_coils)).astype(np.float32)
    currents[:, :3] = [limit, -limit, 0.0]  # the extremes and zero, exactly
    img = r.draw_numpy(currents)
    layers = len(coilset.coils.layers)
    assert img.shape == r.shape == (2 * (layout.shape[1] * 48 + 2) + 2, layers * (layout.shape[0] * 48 + 2) + 2, 3)
    for row, w in enumerate(worlds):
        for k, (x, y, _) in enumerate(coilset.centers):
            got = img[r.pixel(x, y, row, _layer_of(coilset, k))].astype(np.float64)
            np.testing.assert_allclose(got, _expected(currents[w, k] / limit), atol=1.0, err_msg=f"{rng} coil {k}")
            if abs(currents[w, k]) > 0.2 * limit:  # the sign reads off the colour
                assert (got[0] > got[2]) == (currents[w, k] > 0), (rng, k, got)
    np.testing.assert_array_equal(img[r.pixel(0.36, 0.36, 0, 0)], colors.HOLE)  # the missing tile's middle
    np.testing.assert_array_equal(img[r.pixel(0.36, 0.36, 1, 1)], colors.HOLE)
    np.testing.assert_array_equal(img[0, 0], colors.BACKGROUND)
    # a coil's edge is drawn: one pixel inside the left edge of coil 0
    xmin, _, _, _ = coilset.rects[0]
    x, y = coilset.centers[0, :2]
    np.testing.assert_array_equal(img[r.pixel(xmin + 0.4 / r.px_per_m, y, 0, _layer_of(coilset, 0))], colors.COIL_EDGE)


def test_movers_outlined_on_top_with_their_heading():
    layout = Layout.grid(2, 2)
    coilset = CoilSet.build(layout)
    mover = MoverSpec()
    r = CoilCurrentRenderer(coilset, mover, px_per_tile=96, device="cpu")
    currents = np.full(coilset.num_coils, 3.5, np.float32)
    yaw = 0.5 * math.pi  # a quarter turn: the heading tick points along +y
    pos = np.array([[[0.2, 0.25, 0.01]]])
    quat = np.array([[[0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)]]])
    img = r.draw_numpy(currents, pos, quat)
    h = 0.5 * mover.size[0] - 0.5 / r.px_per_m  # half a pixel inside the footprint's edge
    for layer in range(2):
        for dx, dy in ((h, 0.0), (-h, 0.0), (0.0, h), (0.0, -h)):
            np.testing.assert_array_equal(img[r.pixel(0.2 + dx, 0.25 + dy, 0, layer)], colors.MOVER_OUTLINE)
        np.testing.assert_array_equal(img[r.pixel(0.2, 0.25 + 0.3 * h, 0, layer)], colors.MOVER_OUTLINE)  # the tick
        inside = img[r.pixel(0.2 + 0.3 * h, 0.25 - 0.6 * h, 0, layer)].astype(np.float64)
        assert np.abs(inside - _expected(0.5)).max() <= 1.0 or np.array_equal(inside, colors.COIL_EDGE)
    no_movers = r.draw_numpy(currents)
    assert not np.array_equal(no_movers, img)
    assert not (no_movers == np.asarray(colors.MOVER_OUTLINE, np.uint8)).all(-1).any()


def test_bad_inputs_are_refused():
    coilset = CoilSet.build(Layout.grid(1, 1))
    r = CoilCurrentRenderer(coilset, worlds=2, px_per_tile=8, device="cpu")
    with pytest.raises(ValueError, match="currents must have shape"):
        r.draw(np.zeros((2, coilset.num_coils + 1)))
    with pytest.raises(ValueError, match="renderer shows world 1"):
        r.draw(np.zeros((3, coilset.num_coils))[:0].reshape(0, coilset.num_coils))
    with pytest.raises(ValueError, match="current_limit"):
        CoilCurrentRenderer(coilset, current_limit=-1.0)
    with pytest.raises(TypeError, match="CoilSet"):
        CoilCurrentRenderer(Layout.grid(1, 1))
    with pytest.raises(TypeError, match="MagneticDrive or a CoilActuator"):
        drive_currents(object())


def test_levitation_env_renders_its_coil_currents():
    from magwarp.envs.levitation import LevitationEnv
    from magwarp.policies.levitation import LevitationPD

    env = LevitationEnv(2, magnetics=MAG, device="cpu", seed=0, render_mode="rgb_array")
    policy = LevitationPD(env)
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        obs = env.step(policy(obs))[0]
    currents, n = drive_currents(env.actuator)
    ids = env.actuator.coil_ids.numpy().reshape(2, -1)
    slot = env.actuator.applied_currents.numpy().reshape(2, -1)
    want = np.zeros((2, n))
    for w in range(2):
        np.add.at(want[w], ids[w][ids[w] >= 0], slot[w][ids[w] >= 0])
    np.testing.assert_allclose(currents.numpy(), want, rtol=1e-6, atol=1e-6)
    assert np.abs(want).max() > 1.0  # the mover hovers: its coils carry amperes
    frame = env.render()
    _, r, strip = env._coil_renderer
    assert frame.shape == (r.height + strip.shape[0], r.width, 3) and frame.dtype == np.uint8
    coilset = env.actuator.model.coilset
    k = int(np.argmax(np.abs(want[1])))  # world 1's strongest coil, away from its mover's outline
    got = frame[r.pixel(*coilset.centers[k, :2], 1, _layer_of(coilset, k))].astype(np.float64)
    assert np.abs(got - _expected(want[1, k] / env.current_limit)).max() <= 1.0 or np.array_equal(
        got, colors.MOVER_OUTLINE)
    np.testing.assert_array_equal(frame, env.render_coils())


def test_trajectory_env_with_magnetic_model_and_without():
    import gymnasium as gym

    env = gym.make_vec("magwarp/TrajectoryPlanningB0-v0", num_envs=1, device="cpu", render_mode="rgb_array",
                       force_model=MAG)
    env.reset(seed=0)
    env.step(torch.zeros(env.action_space.shape))
    image = env.render_coils()
    assert image.ndim == 3 and image.shape[1] > image.shape[0]  # two layer panels side by side
    normal = env.render()  # render() keeps the mover-level view
    assert normal.shape != image.shape
    ideal = gym.make_vec("magwarp/TrajectoryPlanningB0-v0", num_envs=1, device="cpu", render_mode="rgb_array")
    ideal.reset(seed=0)
    assert ideal.coil_source() is None
    with pytest.raises(ValueError, match="no magnetic model.*force_model='magnetic'"):
        ideal.render_coils()
    assert ideal.render().shape == normal.shape


def test_view_command_writes_coil_videos_and_refuses_ideal_envs(capsys, tmp_path, monkeypatch):
    import imageio.v3 as iio

    from magwarp import cli
    from magwarp.commands import view
    from magwarp.envs.levitation import LevitationEnv

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    # the coarse model of these tests instead of the default one (whose table takes a while to build)
    monkeypatch.setattr(view, "make_env", lambda args, render_mode=None: LevitationEnv(
        1, magnetics=MAG, device="cpu", render_mode=render_mode))
    path = str(tmp_path / "coils.gif")
    rc = cli.main(["view", "magwarp/Levitation-v0", "--viewer", "coils", "--steps", "3", "-o", path])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert "3 frames" in out
    frames = iio.imread(path)
    assert frames.shape[0] == 3 and frames.shape[2] > frames.shape[1]  # two layer panels side by side
    monkeypatch.undo()
    rc = cli.main(["view", "magwarp/TrajectoryPlanningB0-v0", "--viewer", "coils", "--steps", "1", "--device", "cpu",
                   "-o", path])
    _, err = capsys.readouterr()
    assert rc != 0 and "no magnetic model" in err and "force_model" in err


def test_colour_bar_shows_the_map_from_minus_to_plus_the_limit():
    coilset = CoilSet.build(Layout.grid(1, 1))
    r = CoilCurrentRenderer(coilset, px_per_tile=96, current_limit=5.0, device="cpu")
    strip = r.colorbar()
    assert strip.dtype == np.uint8 and strip.shape[1] == r.width and strip.shape[0] > 40
    bar = strip[6 + 6, 6:r.width - 6].astype(np.float64)  # the bar's middle row, left to right
    np.testing.assert_allclose(bar, _expected(np.linspace(-1.0, 1.0, len(bar))), atol=0.0)
    assert bar[0, 2] > bar[0, 0] + 100 and bar[-1, 0] > bar[-1, 2] + 100  # blue at -5 A, red at +5 A
    with pytest.raises(ValueError, match="at least 40 pixels"):
        r.colorbar(10)
