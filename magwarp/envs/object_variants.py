"""Random object sizes and masses per episode (MagBotSim's ``object_ranges``) without a model rebuild.

MagBotSim draws the object's width, height, depth, segment width, radius and mass from ranges at every reset and
rebuilds its MuJoCo model. Here the draws happen once: ``count`` variants are sampled from the ranges, each scene is
compiled by MuJoCo C (so masses, inertias, centres of mass and principal axes come from MuJoCo's own compiler,
for every shape), and their object-dependent model arrays are kept as a bank on the device. A reset then gives
each world a random variant by copying its rows into per-world mujoco-warp model arrays
(:meth:`magwarp.physics.MjwBackend.batch_model_fields`): a gather, no host work, no recompilation. The draw is
from ``count`` samples of the ranges rather than from the continuous ranges themselves.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping

import mujoco
import numpy as np
import torch

from magwarp._checks import as_count
from magwarp.mjcf import ObjectSpec

#: the object parameters that may vary (MagBotSim's ``object_ranges`` keys), as ObjectSpec field names
RANGE_KEYS = ("width", "height", "depth", "segment_width", "radius", "mass")

#: mujoco-warp model arrays that depend on the object's size and mass (same layout as MuJoCo C's)
MODEL_FIELDS = ("body_mass", "body_subtreemass", "body_inertia", "body_ipos", "body_iquat", "body_invweight0",
                "dof_invweight0", "geom_size", "geom_pos", "geom_quat", "geom_aabb", "geom_rbound")


def check_ranges(ranges: Mapping[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
    """Validated ``{key: (low, high)}`` with 0 < low <= high; names the bad key or value."""
    if not isinstance(ranges, Mapping):
        raise ValueError(f"object_ranges must be a mapping of {RANGE_KEYS} to (low, high), got {type(ranges).__name__}")
    out = {}
    for key, value in ranges.items():
        if key not in RANGE_KEYS:
            raise ValueError(f"object_ranges has an unknown key {key!r}; known: {', '.join(RANGE_KEYS)}")
        try:
            lo, hi = (float(v) for v in value)
        except (TypeError, ValueError):
            raise ValueError(f"object_ranges[{key!r}] must be a pair (low, high), got {value!r}") from None
        if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
            raise ValueError(f"object_ranges[{key!r}] must satisfy 0 < low <= high, got {value!r}")
        out[key] = (lo, hi)
    return out


@dataclasses.dataclass
class ObjectVariants:
    """``count`` object variants: their specs and, per model field, a device tensor ``[count, ...]`` of rows."""

    specs: list[ObjectSpec]
    fields: dict[str, torch.Tensor]
    depth: torch.Tensor  # [count] half height of each variant (its resting height above the support)

    @property
    def count(self) -> int:
        return len(self.specs)


def build_variants(base: ObjectSpec, ranges: Mapping[str, tuple[float, float]], count: int,
                   scene_xml: Callable[[ObjectSpec], str], rng: np.random.Generator, device) -> ObjectVariants:
    """Sample ``count`` variants of ``base`` within ``ranges`` and compile ``scene_xml(spec)`` for each."""
    count = as_count(count, "object_variants")
    ranges = check_ranges(ranges)
    specs, rows = [], {name: [] for name in MODEL_FIELDS}
    for _ in range(int(count)):
        values = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in ranges.items()}
        spec = dataclasses.replace(base, **values)
        model = mujoco.MjModel.from_xml_string(scene_xml(spec))
        specs.append(spec)
        for name in MODEL_FIELDS:
            rows[name].append(np.array(getattr(model, name), dtype=np.float32))
    fields = {name: torch.as_tensor(np.stack(r), device=device) for name, r in rows.items()}
    fields["geom_aabb"] = fields["geom_aabb"].reshape(count, -1, 2, 3)  # C: [ngeom, 6] -> mujoco-warp: [ngeom, 2, 3]
    depth = torch.tensor([s.depth for s in specs], dtype=torch.float32, device=device)
    return ObjectVariants(specs, fields, depth)
