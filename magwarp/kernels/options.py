"""Compilation options shared by the simulator's step and collision kernels.

``MAGWARP_KERNEL_OPTIONS`` (e.g. ``"fast_math=1,default_grid_stride=0"``) overrides them, read once at import: a
tuning knob for benchmarks (each setting is a separate kernel-cache entry), not an API.
"""

from __future__ import annotations

import os

# Defaults chosen by benchmarks/scaling.py on an H200 (see benchmarks/RESULTS.md).
DEFAULT_OPTIONS: dict[str, bool] = {}


def _parse(text: str) -> dict[str, bool]:
    out: dict[str, bool] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        key, sep, value = item.partition("=")
        if not sep or value not in ("0", "1"):
            raise ValueError(f"MAGWARP_KERNEL_OPTIONS entries must look like name=0 or name=1, got {item!r}")
        out[key.strip()] = value == "1"
    return out


MODULE_OPTIONS: dict[str, bool] = {**DEFAULT_OPTIONS, **_parse(os.environ.get("MAGWARP_KERNEL_OPTIONS", ""))}
