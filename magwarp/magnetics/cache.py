"""The on-disk cache of built magnetic models (field tables, measured active radii).

Files live in ``$MAGWARP_CACHE_DIR`` when set, else ``~/.cache/magwarp/magnetics`` (outside the repository, so
nothing to git-ignore), named by what they hold and a hash of every parameter that shapes them; a changed parameter
means a new file, never a stale one. Files are ``.npz`` written atomically (a temporary name, then a rename).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

__all__ = ["cache_dir", "cached_arrays"]


def cache_dir() -> Path:
    """The cache folder (created on first use)."""
    env = os.environ.get("MAGWARP_CACHE_DIR")
    path = Path(env) if env else Path.home() / ".cache" / "magwarp" / "magnetics"
    path.mkdir(parents=True, exist_ok=True)
    return path


def cached_arrays(name: str, key: str, build: Callable[[], dict[str, np.ndarray]],
                  use_cache: bool = True) -> dict[str, np.ndarray]:
    """The arrays ``build()`` returns, read from ``<cache_dir>/<name>-<key>.npz`` when present, else built and
    stored there. ``use_cache=False`` builds without reading or writing."""
    if not use_cache:
        return build()
    path = cache_dir() / f"{name}-{key}.npz"
    if path.exists():
        with np.load(path) as data:
            return {k: data[k] for k in data.files}
    arrays = build()
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
    return arrays
