"""A live top-down view of one big world: frames of the swarm renderer (:mod:`magwarp.render.swarm`) shown in a
window as they are simulated, or written to a video file where there is no display.

* :class:`FrameWindow`: a Tk window (the standard library's ``tkinter``, no extra package) that shows ``uint8
  [H, W, 3]`` frames; closing it ends the run;
* :func:`display_available`: whether a window can open here (an X or Wayland display and a working Tk);
* :class:`LiveView`: one sink for the frames: the window when a display exists (``mode="auto"``/``"window"``),
  else a :class:`~magwarp.record.VideoRecorder` (``.mp4``/``.gif``).

Frames are drawn on the device by the renderer; only the finished image crosses to the host (one copy per frame).
"""

from __future__ import annotations

import os

import numpy as np

from magwarp.record import VideoRecorder
from magwarp.render import to_numpy_image

__all__ = ["FrameWindow", "LiveView", "display_available", "LIVE_MODES"]

LIVE_MODES = ("auto", "window", "video")


def display_available() -> bool:
    """True where a Tk window can open (a ``DISPLAY`` or ``WAYLAND_DISPLAY`` and a Tk that connects to it)."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False
    try:
        import tkinter

        root = tkinter.Tk()
        root.destroy()
        return True
    except Exception:  # no Tk, or the display refuses the connection
        return False


def _ppm(image: np.ndarray) -> bytes:
    h, w = image.shape[:2]
    return b"P6 %d %d 255 " % (w, h) + np.ascontiguousarray(image[..., :3]).tobytes()


class FrameWindow:
    """A window showing ``uint8 [H, W, 3]`` frames (Tk's photo image, fed as PPM). :attr:`open` turns false when
    the user closes it."""

    def __init__(self, title: str = "magwarp"):
        import tkinter

        self._tk = tkinter
        self.root = tkinter.Tk()
        self.root.title(title)
        self.root.protocol("WM_DELETE_WINDOW", self.close)
        self.label = tkinter.Label(self.root)
        self.label.pack()
        self.photo = None
        self.open = True

    def show(self, frame) -> None:
        if not self.open:
            return
        self.photo = self._tk.PhotoImage(data=_ppm(to_numpy_image(frame)), format="PPM")
        self.label.configure(image=self.photo)
        self.root.update()

    def close(self) -> None:
        if self.open:
            self.open = False
            self.root.destroy()


class LiveView:
    """Where the frames go: a window (``mode="window"``, or ``"auto"`` with a display) or the video file ``path``
    (``mode="video"``, or ``"auto"`` without a display). :attr:`target` says which one was chosen."""

    def __init__(self, mode: str = "auto", *, path: str | None = None, fps: float = 25.0, title: str = "magwarp"):
        if mode not in LIVE_MODES:
            raise ValueError(f"unknown live view mode {mode!r}; choose one of {list(LIVE_MODES)}")
        if mode == "auto":
            mode = "window" if display_available() else "video"
        if mode == "window":
            self.window, self.video = FrameWindow(title), None
            self.target = "window"
        else:
            if not path:
                raise ValueError("without a window the live view writes a video: give a .mp4 or .gif path")
            self.window, self.video = None, VideoRecorder(path, fps)
            self.target = path
        self.frames = 0

    @property
    def running(self) -> bool:
        return self.window is None or self.window.open

    def show(self, frame) -> None:
        image = to_numpy_image(frame)
        if self.window is not None:
            self.window.show(image)
        else:
            self.video.add(image)
        self.frames += 1

    def close(self) -> str:
        """Close the window or finish the video; returns the target."""
        if self.window is not None:
            self.window.close()
        elif self.video is not None and not self.video.closed:
            self.video.close()
        return self.target
