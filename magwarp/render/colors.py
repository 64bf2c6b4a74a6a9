"""The renderer's palette, as RGB bytes, in one place so tests and legends use the same values.

Choices: tiles light and quiet so movers stand out; holes dark grey with a hatch (a "hole" reads as missing floor);
movers in a colour-blind-friendly qualitative palette that leaves red out, because red means "collided".
"""

from __future__ import annotations

import numpy as np

BACKGROUND = (32, 32, 36)  # separators between mosaic cells
TILE = (226, 228, 232)
TILE_LINE = (170, 174, 182)  # tile borders (grid lines)
HOLE = (84, 86, 92)  # missing tile
HOLE_HATCH = (70, 72, 78)
OBSTACLE = (60, 64, 74)
OBSTACLE_EDGE = (20, 22, 26)
OBJECT = (196, 142, 74)  # pushable objects: wood-like tan
OBJECT_EDGE = (110, 72, 30)
OBJECT_GOAL = (60, 170, 90)  # where the object should go: translucent green
COLLISION = (214, 39, 40)  # halo (safety zone) of a collided mover
HEADING = (255, 255, 255)  # line from the mover's centre towards its +x side (shows yaw)
GOAL_RING = (25, 25, 28)  # dark ring around a goal disc

# Mover colours, cycled by mover index (Okabe-Ito / tab10 inspired, red left out on purpose).
MOVER_PALETTE = (
    (31, 119, 180),  # blue
    (44, 160, 44),  # green
    (148, 103, 189),  # purple
    (255, 127, 14),  # orange
    (23, 190, 207),  # cyan
    (227, 119, 194),  # pink
    (188, 189, 34),  # olive
    (140, 86, 75),  # brown
    (127, 127, 127),  # grey
    (0, 84, 147),  # dark blue
)

# Per-mover states of big swarms (TopDownRenderer.draw(..., state=...)), in this order.
STATE_NAMES = ("moving", "idle", "collided", "carrying", "waiting")
STATE_PALETTE = (
    (31, 119, 180),  # moving: blue
    (188, 189, 34),  # idle (slower than 5 cm/s away from its goal): olive
    (214, 39, 40),  # collided this step: red
    (255, 127, 14),  # carrying a job (material flow): orange
    (90, 90, 90),  # waiting for a free spot to respawn: dark grey
)

# Opacities of translucent layers.
SAFETY_ZONE_ALPHA = 0.22  # fill of the collision shape (+ margin) around a mover
GOAL_LINE_ALPHA = 0.45  # line from a mover to its goal
OBJECT_GOAL_ALPHA = 0.45
COLLIDED_ZONE_ALPHA = 0.45  # safety zone of a collided mover, in COLLISION red


# Coil currents (the coil-current view, magwarp.render.coils): a diverging map over current / limit in [-1, 1]
# (ColorBrewer RdBu, 5 classes, reversed: negative blue, zero near white, positive red), linear between anchors.
CURRENT_ANCHORS = (
    (33, 102, 172),  # -1: -limit
    (146, 197, 222),  # -0.5
    (247, 247, 247),  # 0: no current
    (244, 165, 130),  # +0.5
    (178, 24, 43),  # +1: +limit
)
COIL_EDGE = (150, 150, 158)  # thin line around every coil
MOVER_OUTLINE = (20, 22, 26)  # the mover's footprint (and heading tick) over the coils


def current_rgb(share) -> np.ndarray:
    """RGB bytes (float32 ``[..., 3]``, 0..255) of coil currents given as shares of the limit (values beyond +-1 get
    the end colours): the numpy twin of the coil-current kernel's map."""
    x = np.clip(np.asarray(share, dtype=np.float64), -1.0, 1.0)
    anchors = np.asarray(CURRENT_ANCHORS, dtype=np.float64)
    t = (x + 1.0) * 0.5 * (len(anchors) - 1)
    k = np.minimum(np.floor(t).astype(np.int64), len(anchors) - 2)
    f = (t - k)[..., None]
    return ((1.0 - f) * anchors[k] + f * anchors[k + 1]).astype(np.float32)


def mover_color(index: int) -> tuple[int, int, int]:
    """The colour of mover ``index`` (cycles through :data:`MOVER_PALETTE`)."""
    return MOVER_PALETTE[index % len(MOVER_PALETTE)]


def as_unit_floats(rgb) -> np.ndarray:
    """RGB bytes -> float32 in [0, 1] (the kernel blends in floats)."""
    return np.asarray(rgb, dtype=np.float32) / 255.0
