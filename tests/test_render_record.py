"""Video recording: files written and read back, the RecordVideo wrapper, clear errors."""

from __future__ import annotations

import os

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from magwarp.layout import benchmark_layout
from magwarp.record import RecordVideo, VideoRecorder, ffmpeg_available
from magwarp.render import SyntheticScene, save_png


def _frames(n=6):
    layout, m = benchmark_layout("B1")
    scene = SyntheticScene(layout, num_worlds=4, num_movers=m, seed=1)
    r = scene.make_renderer(px_per_tile=10)  # odd-free sizes are padded for mp4 anyway
    out = []
    for _ in range(n):
        scene.step()
        out.append(scene.draw(r).clone())
    return out


@pytest.mark.parametrize("ext", ["gif", "mp4"])
def test_video_written_and_readable(tmp_path, ext):
    if ext == "mp4" and not ffmpeg_available():
        pytest.skip("imageio-ffmpeg not installed")
    frames = _frames()
    path = tmp_path / f"run.{ext}"
    with VideoRecorder(path, fps=10) as video:
        for f in frames:
            video.add(f)
    assert video.num_frames == len(frames) and os.path.getsize(path) > 0
    back = iio.imread(path)
    h, w = frames[0].shape[:2]
    assert back.shape[0] == len(frames) and back.shape[3] == 3
    assert back.shape[1] >= h and back.shape[2] >= w and back.shape[1] - h <= 1 and back.shape[2] - w <= 1
    if ext == "gif":  # lossless palette for these few colours: the first frame comes back exactly
        assert np.array_equal(back[0][:h, :w], frames[0].numpy())
    else:  # lossy: close on average
        assert np.abs(back[0][:h, :w].astype(int) - frames[0].numpy().astype(int)).mean() < 12


def test_png_and_scale(tmp_path):
    f = _frames(1)[0]
    p = save_png(tmp_path / "f.png", f, scale=2)
    back = iio.imread(p)
    assert back.shape == (2 * f.shape[0], 2 * f.shape[1], 3)
    assert np.array_equal(back[::2, ::2], f.numpy())


def test_recorder_errors(tmp_path):
    with pytest.raises(ValueError, match="must end in one of"):
        VideoRecorder(tmp_path / "x.avi")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        VideoRecorder(tmp_path / "missing" / "x.gif")
    v = VideoRecorder(tmp_path / "x.gif")
    v.add(np.zeros((4, 6, 3), np.uint8))
    with pytest.raises(ValueError, match="frame 1 has shape"):
        v.add(np.zeros((4, 8, 3), np.uint8))
    with pytest.raises(ValueError, match="uint8 image"):
        v.add(np.zeros((4, 6), np.uint8))
    v.close()
    with pytest.raises(RuntimeError, match="no frames"):
        VideoRecorder(tmp_path / "empty.gif").close()


class CountingEnv:
    """Anything with reset/step/render works with RecordVideo."""

    def __init__(self):
        self.t = 0
        self.closed = False
        self.num_envs = 3

    def reset(self, seed=None):
        self.t = 0
        return self.t, {}

    def step(self, action):
        self.t += 1
        return self.t, 0.0, False, False, {}

    def render(self):
        img = np.zeros((8, 10, 3), np.uint8)
        img[:, : self.t % 10] = 255
        return torch.from_numpy(img)

    def close(self):
        self.closed = True


def test_record_video_wrapper(tmp_path):
    env = RecordVideo(CountingEnv(), tmp_path / "videos", step_trigger=lambda s: s % 10 == 0, video_length=4,
                      format="gif", fps=5)
    assert env.num_envs == 3, "attributes pass through to the env"
    env.reset(seed=0)
    for _ in range(25):
        env.step(None)
    env.close()
    assert env.env.closed
    names = sorted(os.path.basename(p) for p in env.videos)
    assert names == ["magwarp-step-0.gif", "magwarp-step-10.gif", "magwarp-step-20.gif"]
    first = iio.imread(env.videos[0])
    assert first.shape[0] == 5, "reset frame + 4 steps"
    assert iio.imread(env.videos[1]).shape[0] == 4


def test_record_video_needs_render():
    with pytest.raises(TypeError, match="needs an env with render"):
        RecordVideo(object(), "x")


def test_tile_frames_and_as_frame():
    from magwarp.record import as_frame, tile_frames

    frames = [np.full((4, 5, 3), k * 40, np.uint8) for k in range(3)]
    grid = tile_frames(frames, border=1)
    assert grid.shape == (2 * 5 + 1, 2 * 6 + 1, 3)
    assert np.all(grid[1:5, 7:12] == 40) and np.all(grid[6:10, 1:6] == 80)
    assert as_frame(frames[:1]) is frames[0]
    assert as_frame(tuple(frames)).shape == tile_frames(frames).shape
    with pytest.raises(ValueError, match="one size"):
        tile_frames([np.zeros((4, 5, 3), np.uint8), np.zeros((5, 5, 3), np.uint8)])


def test_record_video_with_a_magwarp_env(tmp_path):
    gym = pytest.importorskip("gymnasium")
    try:
        import magwarp.envs  # noqa: F401
    except Exception as e:  # noqa: BLE001 - envs are another module's job
        pytest.skip(f"magwarp.envs not importable: {e}")
    if "magwarp/TrajectoryPlanningB0-v0" not in gym.registry:
        pytest.skip("trajectory planning env not registered")
    env = gym.make_vec("magwarp/TrajectoryPlanningB0-v0", num_envs=2, render_mode="rgb_array")
    env = RecordVideo(env, tmp_path, video_length=3, format="gif")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(3):  # moving movers: gif writers merge identical consecutive frames
        env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
    env.close()
    assert len(env.videos) == 1
    assert iio.imread(env.videos[0]).shape[0] == 4
