"""Per-world contact flags from mujoco-warp's contact list (e.g. mover-obstacle and object-obstacle touches).

mujoco-warp keeps one flat contact list for all worlds (``d.contact.geom``, ``d.contact.worldid``, count in
``d.nacon``). :class:`ContactFlags` tags geoms with a group id and ORs, per world and per step, whether any contact
joined two given groups. It runs as a backend cycle hook, so the check is done every control cycle (as MagBotSim
does) inside the step graph, without host syncs.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
import torch
import warp as wp

from magwarp.physics.backend import MjwBackend, PhysicsInputError

__all__ = ["ContactFlags"]


@wp.kernel
def _contact_flags_kernel(
    # Model:
    geom_group: wp.array[int],
    pair_a: wp.array[int],
    pair_b: wp.array[int],
    # State in:
    nacon: wp.array[int],
    contact_geom: wp.array[wp.vec2i],
    contact_world: wp.array[int],
    # State out:
    flags: wp.array2d[int],
):
    c, p = wp.tid()
    if c >= nacon[0]:
        return
    g = contact_geom[c]
    if g[0] < 0 or g[1] < 0:
        return
    ga = geom_group[g[0]]
    gb = geom_group[g[1]]
    a = pair_a[p]
    b = pair_b[p]
    if (ga == a and gb == b) or (ga == b and gb == a):
        flags[contact_world[c], p] = 1


class ContactFlags:
    """Flags ``[W, P]`` (int32, torch view ``flags_t``): pair ``p`` of geom groups touched during the current step.

    :param backend: the backend whose contacts are read; the check is registered as a cycle hook.
    :param groups: group name -> geom name prefixes (e.g. ``{"mover": ["mover_geom_"], "obstacle": ["obstacle_geom_"]}``).
    :param pairs: pairs of group names to flag, e.g. ``[("mover", "obstacle"), ("object", "obstacle")]``.

    Call :meth:`clear` before each step (the env does it) to make the flags per step. Every contact in the list
    counts (distance below the geoms' margin, i.e. penetration with MuJoCo's default margin 0), as in MagBotSim.
    """

    def __init__(self, backend: MjwBackend, groups: dict[str, Sequence[str]], pairs: Sequence[tuple[str, str]]):
        self.backend = backend
        names = list(groups)
        geom_group = np.full(backend.mjm.ngeom, -1, dtype=np.int32)
        for g in range(backend.mjm.ngeom):
            name = mujoco.mj_id2name(backend.mjm, mujoco.mjtObj.mjOBJ_GEOM, g) or ""
            for k, prefixes in enumerate(groups.values()):
                if any(name.startswith(p) for p in prefixes):
                    geom_group[g] = k
        for a, b in pairs:
            for n in (a, b):
                if n not in groups:
                    raise PhysicsInputError(f"contact pair names unknown group {n!r}; groups are {names}")
        self.pairs = [tuple(p) for p in pairs]
        dev = backend.device
        self._geom_group = wp.array(geom_group, dtype=int, device=dev)
        self._pair_a = wp.array([names.index(a) for a, _ in pairs], dtype=int, device=dev)
        self._pair_b = wp.array([names.index(b) for _, b in pairs], dtype=int, device=dev)
        self.flags = wp.zeros((backend.num_worlds, len(pairs)), dtype=int, device=dev)
        self.flags_t = wp.to_torch(self.flags)
        backend.add_cycle_hook(self._launch)

    def _launch(self) -> None:
        d = self.backend.data
        wp.launch(
            _contact_flags_kernel,
            dim=(d.contact.geom.shape[0], len(self.pairs)),
            inputs=[self._geom_group, self._pair_a, self._pair_b, d.nacon, d.contact.geom, d.contact.worldid],
            outputs=[self.flags],
            device=self.backend.device,
        )

    def clear(self) -> None:
        """Zero all flags (torch op on the flags view; ordered on the device stream, no sync)."""
        self.flags_t.zero_()

    def pair(self, a: str, b: str) -> torch.Tensor:
        """``[W]`` bool: did groups ``a`` and ``b`` touch during the step."""
        for k, p in enumerate(self.pairs):
            if p == (a, b) or p == (b, a):
                return self.flags_t[:, k] != 0
        raise PhysicsInputError(f"pair ({a!r}, {b!r}) is not tracked; tracked pairs are {self.pairs}")
