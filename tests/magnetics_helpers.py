"""Shared setup of the magnetics tests: a coarse magnetic model (tables built in about a second on a CPU) and a
fixture that keeps the built tables in a per-module temporary cache."""

from __future__ import annotations

import pytest

from magwarp.magnetics.drive import MagneticModel
from magwarp.magnetics.fast import FieldTableSpec
from magwarp.magnetics.table import WrenchTableSpec

#: the field table of the tests (coarser than the default)
COARSE_FIELD = FieldTableSpec(step=0.002, z_step=0.001, margin=0.08)


def coarse_model(gap=(0.002, 0.006), z_step: float = 0.001, yaw_steps: int = 16) -> MagneticModel:
    """The default design with a coarse wrench table over ``gap``."""
    return MagneticModel(table=WrenchTableSpec(step=0.004, yaw_steps=yaw_steps, z_step=z_step, gap=gap,
                                               field=COARSE_FIELD))


@pytest.fixture(scope="module", autouse=True)
def magnetics_cache(tmp_path_factory):
    """Build and read the magnetic tables in a temporary folder (import it into a test module to use it)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("MAGWARP_CACHE_DIR", str(tmp_path_factory.mktemp("magnetics_cache")))
    yield
    mp.undo()


@pytest.fixture
def cpu_blocks():
    """Let Warp's CPU run blocks of several threads (cooperative fibers), as a GPU does (import it into a test
    module to use it)."""
    import warp as wp

    saved = wp.config.enable_cpu_blocks
    wp.config.enable_cpu_blocks = True
    yield
    wp.config.enable_cpu_blocks = saved
