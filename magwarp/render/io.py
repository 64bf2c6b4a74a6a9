"""Writing single frames to image files."""

from __future__ import annotations

import os

import numpy as np

from magwarp.render.arrays import to_numpy_image


def upscale(image: np.ndarray, factor: int) -> np.ndarray:
    """Nearest-neighbour upscaling by an integer factor (keeps pixel-art edges crisp)."""
    if int(factor) < 1:
        raise ValueError(f"upscale factor must be >= 1, got {factor}")
    if factor == 1:
        return image
    return np.repeat(np.repeat(image, factor, axis=0), factor, axis=1)


def save_png(path: str | os.PathLike, frame, scale: int = 1) -> str:
    """Write an ``[H, W, 3]`` uint8 frame (torch, warp or numpy) to a PNG file; returns the path."""
    import imageio.v3 as iio  # local: imageio is only needed when writing files

    image = upscale(to_numpy_image(frame), scale)
    path = os.fspath(path)
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise FileNotFoundError(f"cannot write {path}: folder {parent} does not exist")
    write_encoded(path, iio.imwrite("<bytes>", image, extension=".png"))
    return path


def write_encoded(path: str, data: bytes) -> None:
    """Write an image or video encoded in memory. imageio is never handed the path: when it cannot open a file it
    raises, and then raises again from its writer's ``__del__`` (a second traceback after the error line)."""
    with open(path, "wb") as f:
        f.write(data)
