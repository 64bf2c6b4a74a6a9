"""magwarp: a GPU-first batched simulator and RL environment suite for magnetic levitation systems, on NVIDIA Warp.

Importing the package registers its gymnasium env ids (``magwarp/...``) with string entry points, so it is fast:
torch, warp and the envs are imported when first used (``magwarp.Simulator``, ``gymnasium.make(...)``).
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# Public names -> the module that defines them, imported on first access (PEP 562).
_LAZY = {
    "BENCHMARK_LAYOUTS": "magwarp.layout",
    "Layout": "magwarp.layout",
    "LayoutError": "magwarp.layout",
    "MoverSpec": "magwarp.layout",
    "TileSpec": "magwarp.layout",
    "benchmark_layout": "magwarp.layout",
    "Simulator": "magwarp.sim",
    "default_device": "magwarp.sim",
}
__all__ = sorted(_LAZY)


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'magwarp' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


from magwarp.registration import register_envs as _register_envs  # noqa: E402

_register_envs()
