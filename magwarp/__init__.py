"""magwarp: a GPU-first batched simulator and RL environment suite for magnetic levitation systems, on NVIDIA Warp.

Importing the package registers its gymnasium env ids (``magwarp/...``).
"""

from magwarp.layout import BENCHMARK_LAYOUTS, Layout, LayoutError, MoverSpec, TileSpec, benchmark_layout
from magwarp.sim import Simulator, default_device

__version__ = "0.1.0"
__all__ = ["BENCHMARK_LAYOUTS", "Layout", "LayoutError", "MoverSpec", "TileSpec", "Simulator", "benchmark_layout",
           "default_device"]

from magwarp import envs as _envs  # noqa: E402,F401  (registers the gymnasium ids)
