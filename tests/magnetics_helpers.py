"""Shared setup of the magnetics tests: a coarse magnetic model (tables built in about a second on a CPU) and a
fixture that keeps the built tables in a per-module temporary cache."""

from __future__ import annotations

import pytest

from magwarp.layout import Layout
from magwarp.magnetics.drive import MagneticModel
from magwarp.magnetics.fast import FieldTableSpec
from magwarp.magnetics.geometry import MagneticParams, Quadrature
from magwarp.magnetics.table import TableModel, WrenchTableSpec

#: the field table of the tests (coarser than the default)
COARSE_FIELD = FieldTableSpec(step=0.002, z_step=0.001, margin=0.08)


def coarse_model(gap=(0.002, 0.006), z_step: float = 0.001, yaw_steps: int = 16) -> MagneticModel:
    """The default design with a coarse wrench table over ``gap``."""
    return MagneticModel(table=WrenchTableSpec(step=0.004, yaw_steps=yaw_steps, z_step=z_step, gap=gap,
                                               field=COARSE_FIELD))


#: the coarse wrench table of the control-cycle tests (seconds to build on a CPU), on a 3 x 2 layout
CYCLE_PARAMS = MagneticParams(quadrature=Quadrature(order=2, max_interval=0.01), active_radius=0.2)
CYCLE_SPEC = WrenchTableSpec(step=0.003, yaw_steps=24, z_step=0.001, gap=(0.003, 0.005),
                             field=FieldTableSpec(step=0.002, z_step=0.001, margin=0.08))


@pytest.fixture(scope="module")
def cycle_model(tmp_path_factory):
    """The control-cycle tests' table model on the CPU, built in a per-module temporary cache that stays set for the
    module (a GPU test builds the same table there from the cache; import it into a test module to use it)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("MAGWARP_CACHE_DIR", str(tmp_path_factory.mktemp("magnetics_cache")))
    yield TableModel(Layout.grid(3, 2), CYCLE_PARAMS, CYCLE_SPEC, device="cpu")
    mp.undo()


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
