"""Start-pose and goal sampling on the device, with MagBotSim's rules and no host synchronisation per step.

Both are uniform over the valid set: positions in the layout's bounding box shrunk by the collision size plus
margins, with the footprint on the tiles (the simulator's own wall rule, run by a Warp kernel), and for start poses
no two movers within collision distance: the simulator's collision shapes (grown by its per-cycle safety margin,
``MoverSpec.margin``) grown further by the sampling offset, so that no world starts in a mover-mover collision.

* Goals: each step draws ``candidates`` points per mover and takes the first valid one; if none is valid (rare) it
  takes a point from a pool of valid points sampled once at construction.
* Start configurations: a pool of valid joint configurations is sampled by rejection at construction (and again by
  :meth:`PoseSampler.draw_pools` when the env is reseeded), and each reset draws one uniformly. (Rejection per
  step would need the host to know when to stop; the pool keeps every reset a fixed amount of device work.)
"""

from __future__ import annotations

import torch
import warp as wp

from magwarp.kernels.collision import footprints_on_tiles
from magwarp.sim import Simulator
from magwarp.types import SHAPE_CIRCLE


class PoseSampler:
    """Samples valid goal points and start configurations for the movers of a :class:`Simulator`.

    ``offset`` is MagBotSim's sampling safety offset (``collision_params["offset"]``), added on top of the collision
    size and the wall margin. Start configurations also keep the simulator's mover-mover safety margin
    (``sim.model.collision.margin``) between movers: each collision shape is grown by ``margin + offset``.
    """

    #: relative slack on the pair distance test, so that float rounding in the simulator's own (squared) test
    #: can never flag a sampled start configuration
    PAIR_SLACK = 1e-5
    #: rounds of rejection sampling after which a pool with no valid sample at all is given up on (the acceptance
    #: rate is then far below what filling the pool within ``max_rounds`` would need)
    PATIENCE = 20

    def __init__(self, sim: Simulator, offset: float, generator: torch.Generator, *, candidates: int = 4,
                 pool_size: int = 16384, max_rounds: int = 2000):
        if offset < 0:
            raise ValueError(f"sampling offset must be >= 0, got {offset!r}")
        self.sim = sim
        self.offset = float(offset)
        self.candidates = int(candidates)
        self.generator = generator
        self.device = sim.torch_device
        col = sim.model.collision
        self.circle = col.shape == SHAPE_CIRCLE
        self.margin = float(col.margin)  # the simulator's per-cycle mover-mover safety margin
        self.radius = float(sim._radii_np.max())
        self.half = torch.tensor(sim._half_np.max(axis=0), dtype=torch.float32)
        # The sampling box: MagBotSim draws from [size + margins, extent - size - margins] on each axis.
        grow = self.offset + col.wall_margin
        reach = torch.full((2,), self.radius + grow) if self.circle else self.half + grow
        ext = torch.tensor(sim.layout.extent, dtype=torch.float32)
        if bool((ext - 2 * reach <= 0).any()):
            raise ValueError(f"the layout ({sim.layout.extent[0]:.3f} x {sim.layout.extent[1]:.3f} m) is too small for a mover "
                             f"of reach {reach.tolist()} (collision size + wall margin + sampling offset): reduce "
                             f"collision_size, collision_offset_wall or collision_offset")
        # On a full rectangle of tiles every point of the sampling box is valid: no kernel needed per step.
        self.full_rectangle = bool(sim.layout.tiles.all())
        if self.full_rectangle:
            self.candidates = 1  # every candidate is valid: drawing more would only cost memory traffic
        self.lo = reach.to(self.device)
        self.span = (ext - 2 * reach).to(self.device)
        self._pool_args = (int(pool_size), int(max_rounds))
        self.draw_pools(generator)

    def draw_pools(self, generator: torch.Generator) -> None:
        """(Re)draw the goal and start pools with ``generator`` (an env's ``reset(seed=...)`` does, so that the seed
        alone fixes the pools); per-step sampling then uses :attr:`generator` again."""
        per_step, self.generator = self.generator, generator
        try:
            self.goal_pool = self._valid_point_pool(*self._pool_args)
            self.start_pool = self._start_config_pool(*self._pool_args)
        finally:
            self.generator = per_step

    # ------------------------------------------------------------------ primitives
    def uniform(self, *shape: int) -> torch.Tensor:
        """Points uniform in the sampling box, shape ``(*shape, 2)``."""
        u = torch.rand((*shape, 2), generator=self.generator, device=self.device)
        return self.lo + u * self.span

    def on_tiles(self, xy: torch.Tensor) -> torch.Tensor:
        """Bool tensor: footprint (yaw 0, grown by the offset) fully on the tiles, for points ``(..., 2)``."""
        if self.full_rectangle:
            inside = (xy >= self.lo) & (xy <= self.lo + self.span)
            return inside.all(dim=-1)
        flat = xy.reshape(-1, 2).contiguous().float()
        out = torch.empty(flat.shape[0], dtype=torch.int32, device=self.device)
        if flat.shape[0]:
            m = self.sim.model
            with self.sim._on_stream():
                wp.launch(
                    footprints_on_tiles, dim=flat.shape[0], device=m.device,
                    inputs=[m.tiles, m.collision, self.radius, wp.vec2(*self.half.tolist()), self.offset,
                            wp.from_torch(flat, dtype=wp.vec2)],
                    outputs=[wp.from_torch(out)],
                )
        return out.reshape(xy.shape[:-1]).bool()

    def pairs_clear(self, xy: torch.Tensor) -> torch.Tensor:
        """Bool ``(...)`` for configurations ``(..., M, 2)``: no two movers collide (yaw 0) once every collision
        shape is grown by the simulator's safety margin plus the sampling offset."""
        d = xy.unsqueeze(-2) - xy.unsqueeze(-3)  # (..., M, M, 2)
        m = xy.shape[-2]
        eye = torch.eye(m, dtype=torch.bool, device=self.device)
        grow = self.margin + self.offset
        if self.circle:
            r = torch.as_tensor(self.sim._radii_np, dtype=torch.float32, device=self.device) + grow
            hit = d.norm(dim=-1) <= (r.unsqueeze(-1) + r.unsqueeze(-2)) * (1 + self.PAIR_SLACK)
        else:
            h = torch.as_tensor(self.sim._half_np, dtype=torch.float32, device=self.device) + grow
            reach = h.unsqueeze(-2) + h.unsqueeze(-3)
            hit = (d.abs() <= reach * (1 + self.PAIR_SLACK)).all(dim=-1)
        return ~(hit & ~eye).any(dim=-1).any(dim=-1)

    # ------------------------------------------------------------------ pools (construction time)
    def _valid_point_pool(self, size: int, max_rounds: int) -> torch.Tensor:
        found, total = [], 0
        for rnd in range(max_rounds):
            pts = self.uniform(size)
            pts = pts[self.on_tiles(pts)]
            found.append(pts)
            total += len(pts)
            if total >= size:
                return torch.cat(found)[:size]
            if total == 0 and rnd + 1 >= self.PATIENCE:
                break  # not one hit: the valid set is (practically) empty, no need to try all rounds
        raise ValueError("could not find valid goal positions on this layout: the tiles leave no room for a mover of "
                         f"collision size {self.radius if self.circle else self.half.tolist()} m with wall margin and "
                         f"offset {self.offset + self.sim.model.collision.wall_margin:g} m: reduce collision_size")

    def _start_config_pool(self, size: int, max_rounds: int) -> torch.Tensor:
        m = self.sim.num_movers
        found, total = [], 0
        for rnd in range(max_rounds):
            cfg = self.goal_pool[torch.randint(len(self.goal_pool), (4 * size, m), generator=self.generator,
                                               device=self.device)]
            cfg = cfg[self.pairs_clear(cfg)]
            found.append(cfg)
            total += len(cfg)
            if total >= size:
                return torch.cat(found)[:size]
            if total == 0 and rnd + 1 >= self.PATIENCE:
                break  # not one hit: the movers (practically) cannot fit, no need to try all rounds
        size = f"radius {self.radius:g}" if self.circle else f"half size {tuple(round(v, 6) for v in self.half.tolist())}"
        raise ValueError(
            f"could not place {m} movers without collisions on this layout (collision {size} m, safety margin "
            f"{self.margin:g} m, sampling offset {self.offset:g} m): reduce collision_size, safety_margin or "
            f"collision_offset, or choose fewer movers or more tiles")

    # ------------------------------------------------------------------ per-step sampling (no host sync)
    def sample_goals(self, num_envs: int, num_movers: int) -> torch.Tensor:
        """Goals ``(num_envs, num_movers, 2)``, each uniform over the valid points."""
        cand = self.uniform(num_envs, num_movers, self.candidates)
        ok = self.on_tiles(cand)
        first = ok.int().argmax(dim=-1, keepdim=True)  # index of the first valid candidate (0 if none)
        pick = torch.gather(cand, 2, first.unsqueeze(-1).expand(-1, -1, 1, 2)).squeeze(2)
        fallback = self.goal_pool[torch.randint(len(self.goal_pool), (num_envs, num_movers), generator=self.generator,
                                                device=self.device)]
        return torch.where(ok.any(dim=-1, keepdim=True), pick, fallback)

    def sample_starts(self, num_envs: int) -> torch.Tensor:
        """Start configurations ``(num_envs, num_movers, 2)`` drawn uniformly from the pool of valid ones."""
        idx = torch.randint(len(self.start_pool), (num_envs,), generator=self.generator, device=self.device)
        return self.start_pool[idx]
