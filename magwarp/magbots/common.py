"""Helpers shared by the MagBot mechanisms: option checks and the MJCF assembly of N mechanisms on 2N movers."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from magwarp.layout import Layout, LayoutError, MoverSpec
from magwarp.magbots.geometry import MagBotLimitError
from magwarp.mjcf import XmlHooks, generate_mjcf

__all__ = ["mechanism_mjcf", "positive_fields"]


def positive_fields(obj, names: Sequence[str], *, error: type[Exception] = MagBotLimitError,
                    allow_zero: bool = False) -> None:
    """Check (and store as float) the dataclass fields ``names`` of the frozen ``obj``: positive (or, with
    ``allow_zero``, non-negative) finite numbers; ``error`` names the first bad one."""
    owner = type(obj).__name__
    for name in names:
        v = float(getattr(obj, name))
        if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
            kind = "non-negative" if allow_zero else "positive"
            raise error(f"{owner}.{name} must be a {kind} finite number, got {v!r}")
        object.__setattr__(obj, name, v)


def mechanism_mjcf(layout: Layout, xy, label: str, mover: MoverSpec | None,
                   hooks: XmlHooks | Mapping[str, object] | None,
                   mover_xy: Callable[[np.ndarray, float], np.ndarray],
                   mechanism: Callable[[int, np.ndarray, float], XmlHooks], **mjcf_options) -> str:
    """MJCF of ``len(xy)`` mechanisms, mechanism ``i`` on movers ``2i`` and ``2i+1``.

    ``xy`` ``[N, 2]`` are the mechanisms' model positions (checked, ``{label}_xy`` in errors); ``mover_xy(xy,
    mover_z)`` gives the movers' model positions ``[2N, 2]``; ``mechanism(i, xy[i], mover_z)`` its worldbody and
    equality XML, appended to the user ``hooks``. ``mjcf_options`` pass to :func:`magwarp.mjcf.generate_mjcf`."""
    mover = mover or MoverSpec()
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) < 1 or not np.all(np.isfinite(xy)):
        raise LayoutError(f"{label}_xy must be a finite array of shape (N >= 1, 2), got {xy.tolist()!r}")
    mover_z = mover.hover_gap + 0.5 * mover.size[2]
    merged = XmlHooks.coerce(hooks)
    for i in range(len(xy)):
        h = mechanism(i, xy[i], mover_z)
        merged = replace(merged, worldbody=merged.worldbody + "\n" + h.worldbody,
                         equality=merged.equality + "\n" + h.equality)
    return generate_mjcf(layout, 2 * len(xy), mover, mover_xy=mover_xy(xy, mover_z), hooks=merged, **mjcf_options)
