"""A colour key strip to put under top-down frames, so a newcomer can read the picture without the docs.

The strip is drawn once with matplotlib (Agg, no display) in the renderer's exact colours and reused for every frame
of a video: ``with_legend(frame, strip)`` stacks them.
"""

from __future__ import annotations

import numpy as np

from magwarp.render import colors
from magwarp.render.arrays import to_numpy_image

ROW_PX = 18  # height of one row of legend items
FONT_PX = 11


STATE_LABELS = {"moving": "moving", "idle": "idle (stuck away from goal)", "collided": "collided",
                "carrying": "carrying a job", "waiting": "waiting to respawn"}


def _items(objects: bool, obstacles: bool, states=None):
    c = {k: np.asarray(v) / 255.0 for k, v in {
        "tile": colors.TILE, "hole": colors.HOLE, "mover": colors.mover_color(0), "red": colors.COLLISION,
        "object": colors.OBJECT, "goal_area": colors.OBJECT_GOAL, "obstacle": colors.OBSTACLE,
        "ring": colors.GOAL_RING, "line": colors.TILE_LINE}.items()}
    items = [
        (("mover (white line: heading)", "mover"), "mover", c),
        (("safety zone", "safety zone"), "zone", c),
        (("collided (red halo)", "collided"), "collided", c),
        (("goal (mover's colour)", "goal"), "goal", c),
        (("missing tile", "no tile"), "hole", c),
    ]
    if states:  # big swarms: movers coloured by state (colors.STATE_NAMES); goals keep the mover index colours
        for name in states:
            c[f"state_{name}"] = np.asarray(colors.STATE_PALETTE[colors.STATE_NAMES.index(name)]) / 255.0
        items = [((STATE_LABELS[name], name), f"state_{name}", c) for name in states] + [
            (("goal", "goal"), "goal", c), (("missing tile", "no tile"), "hole", c)]
    if objects:
        items += [(("object", "object"), "object", c), (("object goal", "obj. goal"), "object_goal", c)]
    if obstacles:
        items += [(("obstacle", "obstacle"), "obstacle", c)]
    return items


def _swatch(ax, kind: str, x: float, y: float, s: float, c) -> None:
    from matplotlib.patches import Circle, Rectangle

    h = s / 2
    if kind.startswith("state_"):
        ax.add_patch(Rectangle((x + h * 0.4, y - h * 0.6), h * 1.2, h * 1.2, color=c[kind]))
    elif kind == "mover":
        ax.add_patch(Rectangle((x, y - h), s, s, color=c["mover"], ec=c["mover"] * 0.6, lw=1))
        ax.plot([x + h, x + s - 2], [y, y], color="white", lw=1.2)
    elif kind == "zone":
        ax.add_patch(Circle((x + h, y), h, fc=(*c["mover"], 0.22), ec=c["mover"], lw=1.2))
    elif kind == "collided":
        ax.add_patch(Circle((x + h, y), h, fc=(*c["red"], 0.45), ec=c["red"], lw=1.8))
        ax.add_patch(Rectangle((x + h * 0.45, y - h * 0.55), h * 1.1, h * 1.1, color=c["mover"]))
    elif kind == "goal":
        ax.add_patch(Circle((x + h, y), h * 0.6, fc=c["mover"], ec=c["ring"], lw=1))
    elif kind == "hole":
        ax.add_patch(Rectangle((x, y - h), s, s, fc=c["hole"], ec=c["line"], lw=0.8, hatch="////"))
    elif kind == "object":
        ax.add_patch(Rectangle((x, y - h * 0.6), s, h * 1.2, fc=c["object"], ec=np.asarray(colors.OBJECT_EDGE) / 255, lw=1))
    elif kind == "object_goal":
        ax.add_patch(Rectangle((x, y - h * 0.6), s, h * 1.2, fc=(*c["goal_area"], 0.45), ec=c["goal_area"], lw=1))
    elif kind == "obstacle":
        ax.add_patch(Rectangle((x, y - h), s, s, fc=c["obstacle"], ec="black", lw=1))


STRIP_DPI = 100


def strip_canvas(width: int, height: int):
    """``(canvas, ax)``: an off-screen matplotlib canvas of ``width x height`` pixels on the renderer's background,
    its axes in pixels (y down, no frame); ``canvas.draw()`` then ``strip_pixels(canvas, height, width)``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width / STRIP_DPI, height / STRIP_DPI), dpi=STRIP_DPI)
    fig.patch.set_facecolor(np.asarray(colors.BACKGROUND) / 255.0)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.axis("off")
    return canvas, ax


def strip_pixels(canvas, height: int, width: int) -> np.ndarray:
    """The drawn canvas as a contiguous ``uint8 [height, width, 3]`` array."""
    canvas.draw()
    return np.ascontiguousarray(np.asarray(canvas.buffer_rgba())[:height, :width, :3])


def legend_strip(width: int, *, objects: bool = False, obstacles: bool = False, states=None) -> np.ndarray:
    """A ``uint8 [h, width, 3]`` colour key, wrapped onto as many rows as ``width`` needs. ``states``: names of
    :data:`colors.STATE_NAMES` when movers are coloured by state (big swarms)."""
    swatch, gap = 12, 10
    # Flow the items into rows (approximate text widths: ~0.6 em per character); short labels on narrow frames.
    long_items = _items(objects, obstacles, states)
    short = any(swatch + 4 + len(label[0]) * FONT_PX * 0.6 + gap > width for label, _, _ in long_items)
    items = [(label[1] if short else label[0], kind, c) for label, kind, c in long_items]
    widths = [swatch + 4 + int(len(label) * FONT_PX * 0.6) + gap for label, _, _ in items]
    rows, x = [[]], 4
    for item, w in zip(items, widths):
        if x + w > width and rows[-1]:
            rows.append([])
            x = 4
        rows[-1].append((item, x))
        x += w
    height = ROW_PX * len(rows) + 4
    canvas, ax = strip_canvas(width, height)
    ax.set_aspect("equal")
    for r, row in enumerate(rows):
        y = 2 + ROW_PX * r + ROW_PX / 2
        for (label, kind, c), x in row:
            _swatch(ax, kind, x, y, swatch, c)
            ax.text(x + swatch + 4, y, label, color="white", fontsize=FONT_PX * 72 / STRIP_DPI, va="center",
                    ha="left")
    return strip_pixels(canvas, height, width)


def with_legend(frame, strip: np.ndarray) -> np.ndarray:
    """The frame (any array kind) with the legend strip below it (numpy ``uint8``)."""
    image = to_numpy_image(frame)
    if strip.shape[1] != image.shape[1]:
        raise ValueError(f"legend width {strip.shape[1]} does not match the frame width {image.shape[1]}")
    return np.concatenate([image, strip], axis=0)
