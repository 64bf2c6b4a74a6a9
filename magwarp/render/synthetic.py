"""A stand-in scene without the simulator: movers glide towards random goals on a layout.

It produces exactly the arrays the simulator exposes (``pos`` [W, M, 3], ``quat`` [W, M, 4] as x, y, z, w,
``collision`` [W, M] int32 bit flags, ``goals`` [W, M, 2]) so the renderer, recorder, viewer and CLI can be used
and tested before (and independently of) the real simulator. No physics: constant-speed straight lines, and no
avoidance, so collisions do happen and show up red. Collision flags come from the numpy reference oracles.
"""

from __future__ import annotations

import numpy as np
import torch

from magwarp import reference
from magwarp.layout import Layout, MoverSpec
from magwarp.render.topdown import TopDownRenderer, object_parts

COLLISION_MOVER = 1
COLLISION_WALL = 2


class SyntheticScene:
    """``num_worlds`` worlds of ``num_movers`` movers on ``layout``; :meth:`step` advances ``dt`` seconds.

    With ``objects=True`` each world also has a T-shaped object (slowly drifting), its goal pose and two static
    obstacles, to exercise every layer of the renderer.
    """

    def __init__(self, layout: Layout, mover: MoverSpec | None = None, *, num_worlds: int = 1, num_movers: int = 3,
                 seed: int = 0, speed: float = 0.5, dt: float = 0.04, objects: bool = False, device=None):
        self.layout = layout
        self.mover = mover if mover is not None else MoverSpec()
        if int(num_worlds) < 1 or int(num_movers) < 1:
            raise ValueError(f"num_worlds and num_movers must be >= 1, got {num_worlds} and {num_movers}")
        self.num_worlds, self.num_movers = int(num_worlds), int(num_movers)
        centers = layout.tile_centers()
        if self.num_movers > len(centers):
            raise ValueError(f"{num_movers} movers do not fit on a layout with {len(centers)} tiles (one per tile)")
        self.rng = np.random.default_rng(seed)
        self.speed, self.dt = float(speed), float(dt)
        self.device = device
        self.time = 0.0
        self._centers = centers
        # Start at distinct tile centres, chosen per world.
        starts = np.stack([centers[self.rng.permutation(len(centers))[: self.num_movers]] for _ in range(self.num_worlds)])
        self.xy = starts.astype(np.float64)
        self.yaw = self.rng.uniform(-0.3, 0.3, size=(self.num_worlds, self.num_movers))
        self.yaw_rate = self.rng.uniform(-0.5, 0.5, size=(self.num_worlds, self.num_movers))
        self.goals = self._sample_goals((self.num_worlds, self.num_movers))
        self.flags = np.zeros((self.num_worlds, self.num_movers), dtype=np.int32)
        self.objects = bool(objects)
        if self.objects:
            ex, ey = layout.extent
            self.object_shape = object_parts("T")
            self.object_pose = np.tile([0.5 * ex, 0.5 * ey, 0.0], (self.num_worlds, 1))
            self.object_goal = np.tile([0.75 * ex, 0.7 * ey, 0.8], (self.num_worlds, 1))
            self.obstacles = np.array([[0.25 * ex, 0.3 * ey, 0.02, 0.06, 0.0], [0.7 * ex, 0.25 * ey, 0.05, 0.02, 0.4]])
        self._renderer = None
        self._update_flags()

    def _sample_goals(self, shape) -> np.ndarray:
        idx = self.rng.integers(0, len(self._centers), size=shape)
        jitter = self.rng.uniform(-0.03, 0.03, size=shape + (2,))
        return self._centers[idx] + jitter

    def _update_flags(self) -> None:
        wall = reference.wall_collisions(self.layout, self.mover, self.xy, self.yaw)
        flags = np.where(wall, COLLISION_WALL, 0).astype(np.int32)
        for w in range(self.num_worlds):
            for i, j in reference.mover_collision_pairs(self.mover, self.xy[w], self.yaw[w]):
                flags[w, i] |= COLLISION_MOVER
                flags[w, j] |= COLLISION_MOVER
        self.flags = flags

    def step(self) -> None:
        """Move every mover ``speed * dt`` towards its goal; a reached goal is replaced by a new one."""
        delta = self.goals - self.xy
        dist = np.linalg.norm(delta, axis=-1, keepdims=True)
        stride = self.speed * self.dt
        self.xy = np.where(dist <= stride, self.goals, self.xy + delta / np.maximum(dist, 1e-9) * stride)
        reached = np.linalg.norm(self.goals - self.xy, axis=-1) < 1e-6
        if reached.any():
            self.goals[reached] = self._sample_goals((int(reached.sum()),))
        self.yaw = self.yaw + self.yaw_rate * self.dt
        if self.objects:
            self.object_pose[:, 0] += 0.02 * np.sin(2.0 * self.time) * self.dt
            self.object_pose[:, 2] += 0.3 * self.dt
        self.time += self.dt
        self._update_flags()

    def arrays(self) -> dict:
        """The simulator-like arrays of the current state as torch tensors on ``device``."""
        dev = self.device
        z = np.full(self.xy.shape[:2] + (1,), self.mover.hover_z)
        half = 0.5 * self.yaw
        quat = np.stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)], axis=-1)
        out = {
            "pos": torch.as_tensor(np.concatenate([self.xy, z], axis=-1), dtype=torch.float32, device=dev),
            "quat": torch.as_tensor(quat, dtype=torch.float32, device=dev),
            "collision": torch.as_tensor(self.flags, dtype=torch.int32, device=dev),
            "goals": torch.as_tensor(self.goals, dtype=torch.float32, device=dev),
        }
        if self.objects:
            out["object_poses"] = torch.as_tensor(self.object_pose, dtype=torch.float32, device=dev)
            out["object_goals"] = torch.as_tensor(self.object_goal, dtype=torch.float32, device=dev)
            out["obstacles"] = torch.as_tensor(self.obstacles, dtype=torch.float32, device=dev)
        return out

    def make_renderer(self, worlds=None, **kwargs) -> TopDownRenderer:
        """A renderer matching this scene (all worlds by default, or the given count/list)."""
        worlds = self.num_worlds if worlds is None else worlds
        return TopDownRenderer(self.layout, self.mover, worlds=worlds, device=self.device,
                               object_shapes=[self.object_shape] if self.objects else None, **kwargs)

    def draw(self, renderer: TopDownRenderer) -> torch.Tensor:
        """Draw the current state with ``renderer``."""
        a = self.arrays()
        return renderer.draw(a["pos"], a["quat"], flags=a["collision"], goals=a["goals"],
                             object_poses=a.get("object_poses"), object_goals=a.get("object_goals"),
                             obstacles=a.get("obstacles"))

    def render(self) -> np.ndarray:
        """Gymnasium-style ``render()``: a numpy ``uint8 [H, W, 3]`` mosaic of all worlds."""
        if self._renderer is None:
            self._renderer = self.make_renderer()
        return self.draw(self._renderer).cpu().numpy().copy()
