"""The live top-down viewer of one big swarm world (``magwarp view magwarp/Swarm-v0 --num-movers N``): without a
display it writes the frames to a video (real frames, read back: tiles, movers coloured by state); the window path
is driven through a stand-in Tk; bad requests are one-line errors."""

from __future__ import annotations

import os

import numpy as np
import pytest

from magwarp import cli
from magwarp.render import live


def run_cli(capsys, *argv):
    rc = cli.main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def test_view_swarm_without_display_writes_a_video(capsys, tmp_path, monkeypatch):
    import imageio.v3 as iio

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    path = str(tmp_path / "swarm.gif")
    rc, out, err = run_cli(capsys, "view", "magwarp/Swarm-v0", "--num-movers", "300", "--steps", "3", "-o", path,
                           "--device", "cpu", "--max-px", "256", "--env-kwargs", '{"k": 4}')
    assert rc == 0, err
    assert "wrote" in out and "3 frames" in out
    frames = iio.imread(path)
    assert frames.shape[0] == 3 and frames.shape[-1] == 3 and max(frames.shape[1:3]) <= 256
    # the movers are drawn: the frame holds more than the tile colours (every mover is a coloured dot)
    last = frames[-1].reshape(-1, 3)
    assert len(np.unique(last, axis=0)) >= 3
    # a zoomed window of the same world
    rc, out, err = run_cli(capsys, "view", "magwarp/Swarm-v0", "--num-movers", "300", "--steps", "2", "-o", path,
                           "--device", "cpu", "--window", "2,2,2", "--live", "video")
    assert rc == 0, err


class FakeTk:
    """Stands in for ``tkinter`` where no display exists: records the images shown."""

    shown: list = []

    class Tk:
        def title(self, text):
            pass

        def protocol(self, name, fn):
            self.close = fn

        def update(self):
            pass

        def destroy(self):
            pass

    class Label:
        def __init__(self, root):
            pass

        def pack(self):
            pass

        def configure(self, image):
            FakeTk.shown.append(image)

    class PhotoImage:
        def __init__(self, data, format):
            header, _, rest = data.partition(b" 255 ")
            _, w, h = header.split()
            assert format == "PPM" and len(rest) == int(w) * int(h) * 3
            self.size = (int(w), int(h))


def test_window_shows_frames_and_closes(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "tkinter", FakeTk)
    monkeypatch.setenv("DISPLAY", ":99")
    FakeTk.shown = []
    assert live.display_available()
    view = live.LiveView("auto")
    assert view.target == "window" and view.running
    frame = np.zeros((20, 30, 3), np.uint8)
    view.show(frame)
    view.show(frame + 5)
    assert [img.size for img in FakeTk.shown] == [(30, 20), (30, 20)]
    view.window.root.close()  # the user closes the window
    assert not view.running
    view.close()


def test_live_view_errors(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert not live.display_available()
    with pytest.raises(ValueError, match="unknown live view mode"):
        live.LiveView("hologram")
    with pytest.raises(ValueError, match="give a .mp4 or .gif path"):
        live.LiveView("video")
    rc, _, err = run_cli(capsys, "view", "magwarp/Swarm-v0", "--num-movers", "0", "--device", "cpu")
    assert rc != 0 and "--num-movers" in err
    rc, _, err = run_cli(capsys, "view", "magwarp/Swarm-v0", "--num-movers", "20", "-o", str(tmp_path / "x.usda"),
                         "--device", "cpu")
    assert rc != 0 and ".mp4 or .gif" in err
    assert not os.path.exists(tmp_path / "x.usda")
