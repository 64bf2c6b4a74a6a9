"""The magnetic-field model of a planar motor: magnet arrays, tile coils, the exact wrench model (closed-form
cuboid fields, Gauss-Legendre quadrature along coil filaments), the fast field-table model, and commutation
(least-copper-loss coil currents for a wanted wrench). Each module's docstring states its model and its sources.

Modules: :mod:`.geometry` (parameters and layouts of magnets and coils), :mod:`.cuboid` (the cuboid field),
:mod:`.exact` (w = Gamma(q) i, the wrench matrix), :mod:`.commutation`, :mod:`.fast` (the cached field table),
:mod:`.table` (the wrench-table model of the control cycle), :mod:`.cycle` (its look-up and the
commutation in one launch, a block of threads per mover: the CPU's cycle), :mod:`.fast_cycle` (the same with a few
lanes per mover and the no-saturation answer first: the GPU's cycle, 2.3-2.8x faster on an H100),
:mod:`.thread_cycle` (the same with one thread per mover,
float64 or float32: what the simulator's drive runs inside its step kernels), :mod:`.reference` (float64 numpy
references, the test oracles), :mod:`.cache` (the on-disk cache), :mod:`.drive` (the magnetic drive in the simulator:
``Simulator(force_model="magnetic")`` or ``MagneticModel(...)``), :mod:`.actuator` (coil currents as the
simulator's input: the Levitation env's actuator).
"""

from magwarp.magnetics.exact import ExactModel, measure_active_radius, pose_to_pos_quat
from magwarp.magnetics.geometry import (CoilLayer, CoilSet, CoilSpec, Cuboid, MagneticParams, MagneticsError,
                                        MagnetArray, Quadrature, TileCoils, halbach_array)

__all__ = ["CoilLayer", "CoilSet", "CoilSpec", "Cuboid", "ExactModel", "MagneticParams", "MagneticsError",
           "MagnetArray", "Quadrature", "TileCoils", "halbach_array", "measure_active_radius", "pose_to_pos_quat"]
