"""Turning user arrays (torch tensors, warp arrays, numpy arrays, lists) into what the renderer's kernel reads.

The renderer never imports the simulator: it takes plain arrays. Torch is the common currency (zero-copy to and
from Warp), so everything goes through a contiguous float32/int32 tensor on the renderer's device.
"""

from __future__ import annotations

import numpy as np
import torch
import warp as wp


def as_tensor(x, *, device: torch.device, dtype: torch.dtype, name: str) -> torch.Tensor:
    """A contiguous tensor of ``dtype`` on ``device`` (no copy when ``x`` already is one)."""
    if isinstance(x, torch.Tensor):
        t = x
    elif isinstance(x, wp.array):
        t = wp.to_torch(x)
    else:
        try:
            t = torch.as_tensor(np.asarray(x))
        except (TypeError, ValueError) as e:
            raise TypeError(f"{name} must be an array (torch, warp or numpy), got {type(x).__name__}") from e
    if t.is_complex() or not (t.is_floating_point() or t.dtype == torch.bool or not t.dtype.is_signed or t.dtype in (
            torch.int8, torch.int16, torch.int32, torch.int64)):
        raise TypeError(f"{name} must hold real numbers, got dtype {t.dtype}")
    return t.to(device=device, dtype=dtype).contiguous()


def per_world(x, *, trailing: tuple[int, ...], name: str, device: torch.device, dtype=torch.float32,
              num_items: int | None = None, allow_trailing: tuple[int, ...] | None = None) -> torch.Tensor:
    """Validate ``x`` as ``[W, N, *trailing]`` (or ``[N, *trailing]``, shared by all worlds) and return it 3-D/2-D.

    ``trailing`` is the expected shape after the item axis (e.g. ``(2,)`` for xy); ``allow_trailing`` lists other
    accepted last-dimension sizes (e.g. 2 or 3 for positions). ``num_items`` checks N when given.
    """
    t = as_tensor(x, device=device, dtype=dtype, name=name)
    nd = 2 + len(trailing)
    if t.ndim == nd - 1:
        t = t.unsqueeze(0)
    if t.ndim != nd:
        want = "[W, N" + "".join(f", {k}" for k in trailing) + "]"
        raise ValueError(f"{name} must have shape {want} (or without W), got {tuple(t.shape)}")
    if trailing:
        ok = (t.shape[-1],) in ((trailing[-1],),) or (allow_trailing is not None and t.shape[-1] in allow_trailing)
        if not ok:
            sizes = (trailing[-1],) if allow_trailing is None else allow_trailing
            raise ValueError(f"{name} must have last dimension in {sizes}, got shape {tuple(t.shape)}")
    if num_items is not None and t.shape[1] != num_items:
        raise ValueError(f"{name} must have {num_items} items per world (one per mover/object), got shape {tuple(t.shape)}")
    return t


def to_numpy_image(frame) -> np.ndarray:
    """An ``[H, W, 3]`` uint8 frame (torch, warp or numpy, any device) as a fresh numpy array."""
    if isinstance(frame, torch.Tensor):
        arr = frame.detach().cpu().numpy()
    elif isinstance(frame, wp.array):
        arr = frame.numpy()
    else:
        arr = np.asarray(frame)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4) or arr.dtype != np.uint8:
        raise ValueError(f"a frame must be an [H, W, 3] uint8 image, got shape {arr.shape} dtype {arr.dtype}")
    return np.array(arr[:, :, :3], copy=True)


def warp_device(device) -> wp.Device:
    """A Warp device from a Warp device, a name ("cpu", "cuda:0"), a ``torch.device`` or ``None`` (Warp's default)."""
    if isinstance(device, torch.device):
        if device.type == "cuda" and device.index is None:  # torch's "cuda" means its current device
            device = torch.device("cuda", torch.cuda.current_device())
        return wp.device_from_torch(device)
    return wp.get_device(device)
