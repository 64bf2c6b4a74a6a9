"""Videos of magwarp runs: a frame-by-frame writer and a wrapper that records any env with ``render()``.

* :class:`VideoRecorder` writes ``.mp4`` (H.264 through imageio-ffmpeg) or ``.gif`` (Pillow) from ``uint8 [H, W, 3]``
  frames (torch tensors on any device, warp arrays or numpy arrays).
* :class:`RecordVideo` wraps an env (anything with ``reset``, ``step`` and ``render() -> [H, W, 3] uint8``) and
  records ``video_length`` steps whenever ``step_trigger(step)`` fires, into numbered files in a folder. It does
  not depend on gymnasium: a gymnasium (vector) env made with ``render_mode="rgb_array"`` works as is, and every
  other attribute is passed through to the env.

Example::

    with VideoRecorder("run.mp4", fps=25) as video:
        for _ in range(100):
            sim.step()
            video.add(renderer.draw(sim.pos, sim.quat, flags=sim.collision))
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from magwarp.render.arrays import to_numpy_image

__all__ = ["VideoRecorder", "RecordVideo", "VIDEO_FORMATS", "ffmpeg_available", "tile_frames", "as_frame"]

VIDEO_FORMATS = (".mp4", ".gif")


def ffmpeg_available() -> bool:
    """True when imageio can write mp4 (the ``imageio-ffmpeg`` package and its bundled ffmpeg are present)."""
    try:
        import imageio_ffmpeg

        return bool(imageio_ffmpeg.get_ffmpeg_exe())
    except Exception:  # noqa: BLE001 - any failure means "no ffmpeg"
        return False


def tile_frames(frames, cols: int | None = None, border: int = 2) -> np.ndarray:
    """Equal-size ``[H, W, 3]`` frames (e.g. one per sub-env of a gymnasium vector env) as one grid image."""
    images = [to_numpy_image(f) for f in frames]
    if not images:
        raise ValueError("tile_frames needs at least one frame")
    h, w = images[0].shape[:2]
    if any(im.shape[:2] != (h, w) for im in images):
        raise ValueError(f"tile_frames needs frames of one size, got {sorted({im.shape[:2] for im in images})}")
    cols = int(cols) if cols else int(np.ceil(np.sqrt(len(images))))
    rows = -(-len(images) // cols)
    from magwarp.render import colors

    grid = np.empty((rows * (h + border) + border, cols * (w + border) + border, 3), np.uint8)
    grid[:] = colors.BACKGROUND
    for k, im in enumerate(images):
        r, c = divmod(k, cols)
        y, x = border + r * (h + border), border + c * (w + border)
        grid[y:y + h, x:x + w] = im
    return grid


def as_frame(rendered) -> np.ndarray:
    """What an env's ``render()`` returned, as one ``uint8 [H, W, 3]`` image: an image as is, a list/tuple of
    images (gymnasium vector envs may return one per sub-env) as a grid."""
    if isinstance(rendered, (list, tuple)):
        return rendered[0] if len(rendered) == 1 else tile_frames(rendered)
    return rendered


class VideoRecorder:
    """Writes frames to ``path`` (``.mp4`` or ``.gif``) at ``fps`` frames per second.

    mp4 frames are streamed to ffmpeg as they come (memory stays flat); gif frames are kept and written on
    :meth:`close` (gifs are for short clips; identical consecutive gif frames are merged into one longer frame, so
    the timing is kept). All frames must have the size of the first. ``scale`` upsamples by an
    integer factor (nearest neighbour), handy for small mosaics.
    """

    def __init__(self, path: str | os.PathLike, fps: float = 25.0, *, scale: int = 1, quality: int = 7):
        self.path = os.fspath(path)
        ext = os.path.splitext(self.path)[1].lower()
        if ext not in VIDEO_FORMATS:
            raise ValueError(f"video path must end in one of {VIDEO_FORMATS}, got {self.path!r}")
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be positive, got {fps!r}")
        if int(scale) < 1:
            raise ValueError(f"scale must be an integer >= 1, got {scale!r}")
        parent = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(parent):
            raise FileNotFoundError(f"cannot write {self.path}: folder {parent} does not exist")
        if ext == ".mp4" and not ffmpeg_available():
            raise RuntimeError("writing mp4 needs the imageio-ffmpeg package (pip install imageio-ffmpeg); or use .gif")
        self.ext, self.fps, self.scale, self.quality = ext, float(fps), int(scale), int(quality)
        self.num_frames = 0
        self._shape = None
        self._writer = None
        self._gif_frames: list[np.ndarray] = []
        self.closed = False

    def add(self, frame) -> None:
        """Append one ``uint8 [H, W, 3]`` frame."""
        if self.closed:
            raise RuntimeError(f"VideoRecorder({self.path!r}) is closed")
        image = to_numpy_image(frame)
        if self.scale > 1:
            image = np.repeat(np.repeat(image, self.scale, axis=0), self.scale, axis=1)
        if self._shape is None:
            self._shape = image.shape
        elif image.shape != self._shape:
            raise ValueError(f"frame {self.num_frames} has shape {image.shape}, the video's frames are {self._shape}")
        if self.ext == ".gif":
            self._gif_frames.append(image)
        else:
            if self._writer is None:
                import imageio.v2 as imageio  # local: only needed when writing

                # H.264 in yuv420p needs even sizes: pad (below/right) instead of letting imageio rescale.
                self._writer = imageio.get_writer(self.path, format="FFMPEG", mode="I", fps=self.fps, codec="libx264",
                                                  quality=self.quality, macro_block_size=1, pixelformat="yuv420p")
            self._writer.append_data(_pad_even(image))
        self.num_frames += 1

    def close(self) -> str:
        """Finish the file; returns its path. Closing twice is harmless."""
        if self.closed:
            return self.path
        self.closed = True
        if self.num_frames == 0:
            raise RuntimeError(f"no frames were added to {self.path}; nothing written")
        if self.ext == ".gif":
            import imageio.v3 as iio

            # Pillow stores gif frame durations in milliseconds; loop=0 repeats forever.
            from magwarp.render.io import write_encoded

            write_encoded(self.path, iio.imwrite("<bytes>", np.stack(self._gif_frames), extension=".gif",
                                                 duration=1000.0 / self.fps, loop=0))
            self._gif_frames = []
        elif self._writer is not None:
            self._writer.close()
        return self.path

    def __enter__(self) -> "VideoRecorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:  # keep the original error; still release ffmpeg
            self.closed = True
            if self._writer is not None:
                self._writer.close()


def _pad_even(image: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return image
    return np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


class RecordVideo:
    """Records videos of ``env`` while it runs: ``env.render()`` after every reset/step of a recording.

    Args:
        env: anything with ``reset(...)``, ``step(action)`` and ``render()`` returning ``uint8 [H, W, 3]``.
        video_folder: output folder (created).
        step_trigger: called with the global step count before each step; ``True`` starts a recording.
            Default: record from the first step.
        video_length: steps per video.
        name_prefix: file names are ``{name_prefix}-step-{step}.{format}``.
        fps: frames per second of the videos (default 25, the 40 ms policy step).
        format: ``"mp4"`` or ``"gif"`` (default mp4 when ffmpeg is available, else gif).
    """

    def __init__(self, env, video_folder: str | os.PathLike, *, step_trigger: Callable[[int], bool] | None = None,
                 video_length: int = 200, name_prefix: str = "magwarp", fps: float = 25.0, format: str | None = None,
                 scale: int = 1):
        if not callable(getattr(env, "render", None)):
            raise TypeError(f"RecordVideo needs an env with render(), got {type(env).__name__}")
        if int(video_length) < 1:
            raise ValueError(f"video_length must be >= 1, got {video_length}")
        fmt = format or ("mp4" if ffmpeg_available() else "gif")
        if f".{fmt}" not in VIDEO_FORMATS:
            raise ValueError(f"format must be 'mp4' or 'gif', got {format!r}")
        self.env = env
        self.video_folder = os.fspath(video_folder)
        os.makedirs(self.video_folder, exist_ok=True)
        self.step_trigger = step_trigger or (lambda step: step == 0)
        self.video_length, self.name_prefix, self.fps, self.format, self.scale = (
            int(video_length), name_prefix, fps, fmt, int(scale))
        self.step_id = 0
        self.videos: list[str] = []  # paths written so far
        self._recorder: VideoRecorder | None = None
        self._recorded = 0

    def __getattr__(self, name):  # everything else is the env's
        if name == "env":  # not set yet (e.g. while unpickling): avoid infinite recursion
            raise AttributeError(name)
        return getattr(self.env, name)

    def _start(self) -> None:
        path = os.path.join(self.video_folder, f"{self.name_prefix}-step-{self.step_id}.{self.format}")
        self._recorder = VideoRecorder(path, self.fps, scale=self.scale)
        self._recorded = 0

    def _capture(self) -> None:
        frame = self.env.render()
        if frame is None:
            raise RuntimeError("env.render() returned None: make the env with render_mode='rgb_array'")
        self._recorder.add(as_frame(frame))

    def _stop(self) -> None:
        if self._recorder is not None:
            self.videos.append(self._recorder.close())
            self._recorder = None

    def reset(self, *args, **kwargs):
        result = self.env.reset(*args, **kwargs)
        if self._recorder is None and self.step_trigger(self.step_id):
            self._start()
        if self._recorder is not None:
            self._capture()
        return result

    def step(self, action):
        if self._recorder is None and self.step_trigger(self.step_id):
            self._start()
        result = self.env.step(action)
        self.step_id += 1
        if self._recorder is not None:
            self._capture()
            self._recorded += 1
            if self._recorded >= self.video_length:
                self._stop()
        return result

    def close(self) -> None:
        """Finish any open video, then close the env (if it has ``close``)."""
        self._stop()
        close = getattr(self.env, "close", None)
        if callable(close):
            close()
