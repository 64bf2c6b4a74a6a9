"""The coil-current view: the tiles' coils seen from above, coloured by their current, with the movers' outlines.

    r = CoilCurrentRenderer(coilset, mover, worlds=2)          # one row per world, one panel per coil layer
    frame = r.draw(currents, pos, quat)                        # currents [W, n_coils] A; torch uint8 [H, W, 3]
    image = with_legend(frame, r.colorbar())                   # the colour bar (A) and the panels' names below it
    frame = r.draw(*drive_currents(env.actuator), pos, quat)   # from a magnetic drive or a coil actuator

The coil layers of a tile lie on top of each other (long sides along y above, along x below, for the default
design), so each layer gets its own panel, side by side; a row of panels per shown world. Every pixel takes the
colour of the coil of its panel's layer under it (:data:`~magwarp.render.colors.CURRENT_ANCHORS`: blue negative,
near white zero, red positive, as a share of ``current_limit``; :func:`~magwarp.render.colors.current_rgb` is the
same map in numpy), a thin grey line marks coil edges, missing tiles are dark, and each mover's footprint (ignoring
its small tilt) is outlined on top with a tick from its centre towards its +x side (its yaw).

A coil is driven for every mover whose window holds it: its current is the sum of those movers' slot currents
(:func:`drive_currents`; the magnetic model treats movers independently, so two movers sharing a coil add up).
Example: ``docs/levitation_coils.png`` (``magwarp view magwarp/Levitation-v0 --viewer coils``, the PD baseline).
One Warp launch per frame, one thread per pixel, looping over the world's movers (the view is for a few movers:
a levitation env, a small trajectory-planning layout).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
import warp as wp

from magwarp._streams import torch_stream
from magwarp.layout import MoverSpec
from magwarp.render import colors
from magwarp.render.arrays import as_tensor, per_world, to_numpy_image, warp_device

__all__ = ["CoilCurrentRenderer", "drive_currents"]


@wp.func
def _current_color(share: float, anchors: wp.array(dtype=wp.vec3)) -> wp.vec3:
    """The diverging map of :func:`colors.current_rgb` (anchors evenly spaced over [-1, 1])."""
    n = anchors.shape[0]
    t = (wp.clamp(share, -1.0, 1.0) + 1.0) * 0.5 * float(n - 1)
    k = wp.min(int(wp.floor(t)), n - 2)
    f = t - float(k)
    return anchors[k] * (1.0 - f) + anchors[k + 1] * f


@wp.kernel
def draw_coil_currents(
    # Model:
    tile_map: wp.array2d(dtype=wp.int32),
    tile_size: float,
    per_tile: int,
    layer_dir: wp.array(dtype=wp.int32),
    coil_width: float,
    coil_length: float,
    cell_world: wp.array(dtype=wp.int32),
    cols: int,
    cell_w: int,
    cell_h: int,
    border: int,
    px_per_m: float,
    half: wp.vec2,
    limit: float,
    anchors: wp.array(dtype=wp.vec3),
    palette: wp.array(dtype=wp.vec3),
    # State in:
    currents: wp.array2d(dtype=float),
    movers: wp.array2d(dtype=wp.vec4),
    # State out:
    image: wp.array3d(dtype=wp.uint8),
):
    """One pixel: the coil of the panel's layer under it, coloured by its current, its edges, the movers' outlines.

    ``palette``: background, hole, coil edge, mover outline. ``movers[w, m]``: x, y, cos(yaw), sin(yaw)."""
    r, c = wp.tid()
    span_w = cell_w + border
    span_h = cell_h + border
    cc = (c - border) // span_w
    rr = (r - border) // span_h
    lc = c - border - cc * span_w
    lr = r - border - rr * span_h
    color = palette[0]
    if c >= border and r >= border and lc < cell_w and lr < cell_h and rr < cell_world.shape[0]:
        layer = cc
        w = cell_world[rr]
        x = (float(lc) + 0.5) / px_per_m
        y = (float(cell_h - 1 - lr) + 0.5) / px_per_m
        i = int(wp.floor(x / tile_size))
        j = int(wp.floor(y / tile_size))
        color = palette[1]
        edge = 1.0 / px_per_m
        if i >= 0 and j >= 0 and i < tile_map.shape[0] and j < tile_map.shape[1] and tile_map[i, j] >= 0:
            lx = x - float(i) * tile_size
            ly = y - float(j) * tile_size
            across_u = lx  # across the coil (its width) and along it (its length)
            along_u = ly
            if layer_dir[layer] == 0:  # long sides along x
                across_u = ly
                along_u = lx
            n_across = int(tile_size / coil_width + 0.5)
            n_along = int(tile_size / coil_length + 0.5)
            a = wp.min(int(wp.floor(across_u / coil_width)), n_across - 1)
            b = wp.min(int(wp.floor(along_u / coil_length)), n_along - 1)
            k = tile_map[i, j] * per_tile + layer * n_across * n_along + a * n_along + b
            color = _current_color(currents[w, k] / limit, anchors)
            da = wp.min(across_u - float(a) * coil_width, float(a + 1) * coil_width - across_u)
            db = wp.min(along_u - float(b) * coil_length, float(b + 1) * coil_length - along_u)
            if wp.min(da, db) < edge:
                color = palette[2]
        line = 1.2 / px_per_m
        for m in range(movers.shape[1]):
            mv = movers[w, m]
            dx = x - mv[0]
            dy = y - mv[1]
            u = mv[2] * dx + mv[3] * dy  # the pixel in the mover's frame
            v = -mv[3] * dx + mv[2] * dy
            if wp.abs(u) <= half[0] and wp.abs(v) <= half[1]:
                rim = wp.min(half[0] - wp.abs(u), half[1] - wp.abs(v)) < line
                tick = wp.abs(v) < line and u > 0.0 and u < 0.6 * half[0]
                if rim or tick:
                    color = palette[3]
    for ch in range(3):
        image[r, c, ch] = wp.uint8(wp.clamp(color[ch] + 0.5, 0.0, 255.0))


def drive_currents(source) -> tuple[torch.Tensor, int]:
    """``(currents [W, n_coils] A float32, n_coils)`` of a magnetic drive (:class:`~magwarp.magnetics.drive.
    MagneticDrive`) or coil actuator (:class:`~magwarp.magnetics.actuator.CoilActuator`): the last cycle's slot
    currents added up per coil over the world's movers (on the device, no host sync)."""
    model = getattr(source, "model", None)
    coilset = getattr(model, "coilset", None)
    if coilset is None or not hasattr(source, "coil_ids"):
        raise TypeError(f"drive_currents needs a MagneticDrive or a CoilActuator, got {type(source).__name__}")
    slots = source.applied_currents if hasattr(source, "applied_currents") else source.currents
    ids = source.coil_ids.to(torch.int64)
    w = ids.shape[0]
    n = coilset.num_coils
    value = torch.where(ids >= 0, slots.to(torch.float32), torch.zeros((), device=slots.device))
    out = torch.zeros((w, n), dtype=torch.float32, device=slots.device)
    out.scatter_add_(1, ids.clamp(min=0).reshape(w, -1), value.reshape(w, -1))
    return out, n


class CoilCurrentRenderer:
    """Draws the coil currents of one or more worlds (see the module docstring).

    Args:
        coilset: the layout's coils (:class:`~magwarp.magnetics.geometry.CoilSet`; a drive's ``model.coilset``).
        mover: the movers' footprint (``MoverSpec.size``); default ``MoverSpec()``.
        worlds: number of worlds to show (``0..n-1``) or their indices: one row of layer panels per world.
        px_per_tile: pixels per tile edge (default 96: a 40 mm coil is 16 pixels wide).
        current_limit: the current (A) at the ends of the colour map (default: the coils' limit).
        border_px: separators between panels.
        device: Warp device, name or ``torch.device`` (default: Warp's preferred device).
    """

    def __init__(self, coilset, mover: MoverSpec | None = None, *, worlds: int | Sequence[int] = 1,
                 px_per_tile: int = 96, current_limit: float | None = None, border_px: int = 2, device=None):
        from magwarp.magnetics.geometry import CoilSet

        if not isinstance(coilset, CoilSet):
            raise TypeError(f"coilset must be a magwarp.magnetics.geometry.CoilSet, got {type(coilset).__name__}")
        self.coilset = coilset
        self.mover = mover if mover is not None else MoverSpec()
        if int(px_per_tile) != px_per_tile or px_per_tile < 1:
            raise ValueError(f"px_per_tile must be an integer >= 1, got {px_per_tile!r}")
        if int(border_px) != border_px or border_px < 0:
            raise ValueError(f"border_px must be an integer >= 0, got {border_px!r}")
        limit = float(coilset.coils.coil.current_limit) if current_limit is None else current_limit
        if not isinstance(limit, (int, float)) or not math.isfinite(limit) or limit <= 0:
            raise ValueError(f"current_limit must be a positive finite number (A), got {current_limit!r}")
        self.current_limit = float(limit)
        shown = np.arange(int(worlds)) if np.ndim(worlds) == 0 else np.asarray(worlds, dtype=np.int64).reshape(-1)
        if len(shown) == 0 or np.any(shown < 0):
            raise ValueError(f"worlds must be a positive count or a list of world indices >= 0, got {worlds!r}")
        self.worlds = shown
        layout = coilset.layout
        self.layers = coilset.coils.layers
        self.px_per_m = int(px_per_tile) / layout.tile.size
        self.border = int(border_px)
        self.cell_w, self.cell_h = layout.shape[0] * int(px_per_tile), layout.shape[1] * int(px_per_tile)
        self.width = len(self.layers) * (self.cell_w + self.border) + self.border
        self.height = len(shown) * (self.cell_h + self.border) + self.border
        self.device = warp_device(device)
        self.torch_device = wp.device_to_torch(self.device)
        dev = self.device
        self._tile_map = wp.array(coilset.tile_map.astype(np.int32), dtype=wp.int32, device=dev)
        dirs = np.array([0 if layer.direction == "x" else 1 for layer in self.layers], np.int32)
        self._dirs = wp.array(dirs, dtype=wp.int32, device=dev)
        self._worlds = wp.array(shown.astype(np.int32), dtype=wp.int32, device=dev)
        self._anchors = wp.array(np.asarray(colors.CURRENT_ANCHORS, np.float32), dtype=wp.vec3, device=dev)
        palette = [colors.BACKGROUND, colors.HOLE, colors.COIL_EDGE, colors.MOVER_OUTLINE]
        self._palette = wp.array(np.asarray(palette, np.float32), dtype=wp.vec3, device=dev)
        self._image = wp.zeros((self.height, self.width, 3), dtype=wp.uint8, device=dev)
        self._image_torch = wp.to_torch(self._image)
        self._keep = None

    @property
    def shape(self) -> tuple[int, int, int]:
        """Image shape ``(H, W, 3)``."""
        return (self.height, self.width, 3)

    def pixel(self, x: float, y: float, world_row: int = 0, layer: int = 0) -> tuple[int, int]:
        """``(row, column)`` of the pixel holding world point ``(x, y)`` (m) in the panel of ``layer`` in the row of
        the ``world_row``-th shown world."""
        c = self.border + layer * (self.cell_w + self.border) + int(math.floor(x * self.px_per_m))
        r = self.border + world_row * (self.cell_h + self.border) + self.cell_h - 1 - int(math.floor(y * self.px_per_m))
        return r, c

    def layer_names(self) -> list[str]:
        """The panels' names, left to right (long sides' direction, top layer first as in the design)."""
        return [f"layer {k}: long sides along {layer.direction} (z {layer.z_top * 1e3:g} mm)"
                for k, layer in enumerate(self.layers)]

    def draw(self, currents, pos=None, quat=None) -> torch.Tensor:
        """The frame (the renderer's own torch ``uint8 [H, W, 3]`` buffer, overwritten by the next call).

        ``currents``: ``[W, n_coils]`` A (or ``[n_coils]``: every shown world); ``pos`` ``[W, M, 2|3]`` and ``quat``
        ``[W, M, 4]`` (x, y, z, w) of the movers to outline (None: no movers)."""
        td = self.torch_device
        n = self.coilset.num_coils
        cur = as_tensor(currents, device=td, dtype=torch.float32, name="currents")
        cur = cur[None] if cur.ndim == 1 else cur
        if cur.ndim != 2 or cur.shape[1] != n:
            raise ValueError(f"currents must have shape [W, {n}] (one per coil of the layout), got {tuple(cur.shape)}")
        need = int(self.worlds.max()) + 1
        if cur.shape[0] < need and cur.shape[0] != 1:
            raise ValueError(f"currents has {cur.shape[0]} worlds; the renderer shows world {need - 1}")
        if cur.shape[0] == 1 and need > 1:
            cur = cur.expand(need, n).contiguous()
        if pos is None:
            movers = torch.zeros((cur.shape[0], 0, 4), dtype=torch.float32, device=td)
        else:
            p = per_world(pos, trailing=(3,), allow_trailing=(2, 3), name="pos", device=td)
            if quat is None:
                yaw = torch.zeros(p.shape[:2], device=td)
            else:
                q = per_world(quat, trailing=(4,), name="quat", device=td, num_items=p.shape[1])
                x, y, z, w = q.unbind(-1)
                yaw = torch.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
            if p.shape[0] < need and p.shape[0] != 1:
                raise ValueError(f"pos has {p.shape[0]} worlds; the renderer shows world {need - 1}")
            movers = torch.stack([p[..., 0], p[..., 1], torch.cos(yaw), torch.sin(yaw)], -1)
            if movers.shape[0] == 1 and need > 1:
                movers = movers.expand(need, *movers.shape[1:])
            movers = movers.contiguous()
        spec = self.coilset.coils.coil
        half = wp.vec2(0.5 * self.mover.size[0], 0.5 * self.mover.size[1])
        self._keep = (cur, movers)
        inputs = [self._tile_map, float(self.coilset.layout.tile.size), int(self.coilset.per_tile), self._dirs,
                  float(spec.width), float(spec.length), self._worlds, len(self.layers), self.cell_w, self.cell_h,
                  self.border, float(self.px_per_m), half, self.current_limit, self._anchors, self._palette,
                  wp.from_torch(cur), wp.from_torch(movers, dtype=wp.vec4)]
        if self.device.is_cuda:
            with wp.ScopedStream(torch_stream(td)):
                wp.launch(draw_coil_currents, dim=(self.height, self.width), inputs=inputs, outputs=[self._image],
                          device=self.device)
        else:
            wp.launch(draw_coil_currents, dim=(self.height, self.width), inputs=inputs, outputs=[self._image],
                      device=self.device)
        return self._image_torch

    def draw_numpy(self, *args, **kwargs) -> np.ndarray:
        """:meth:`draw`, returned as a fresh numpy ``uint8 [H, W, 3]`` array."""
        return to_numpy_image(self.draw(*args, **kwargs))

    def colorbar(self, width: int | None = None) -> np.ndarray:
        """A ``uint8 [h, width, 3]`` strip for under the frame: the colour map from ``-current_limit`` to
        ``+current_limit`` (A, its pixels in the kernel's exact colours) with ticks, and the panels' names."""
        from magwarp.render.legend import strip_canvas, strip_pixels

        width = self.width if width is None else int(width)
        if width < 40:
            raise ValueError(f"colorbar width must be at least 40 pixels, got {width}")
        bar_h, text_h, pad = 12, 14, 6
        names = self.layer_names()
        height = pad + bar_h + text_h + text_h * len(names) + pad
        canvas, ax = strip_canvas(width, height)
        x0, x1 = pad, width - pad
        lim = self.current_limit
        y_text = pad + bar_h + text_h / 2
        for f in (-1.0, -0.5, 0.0, 0.5, 1.0):
            x = x0 + (f + 1.0) / 2.0 * (x1 - x0 - 1)
            ha = "left" if f == -1.0 else "right" if f == 1.0 else "center"
            label = f"{f * lim:+.3g} A" if f else "0 A"
            ax.text(x, y_text, label, color="white", fontsize=8, va="center", ha=ha)
        for k, name in enumerate(names):
            ax.text(x0, y_text + text_h * (k + 1), f"panel {k + 1} (left to right): {name}", color="white",
                    fontsize=8, va="center", ha="left")
        strip = strip_pixels(canvas, height, width)
        shares = np.linspace(-1.0, 1.0, x1 - x0)
        strip[pad:pad + bar_h, x0:x1] = np.floor(colors.current_rgb(shares) + 0.5).astype(np.uint8)[None]
        return strip
