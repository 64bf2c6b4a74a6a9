"""Images and video of magwarp scenes.

* :class:`TopDownRenderer` draws tiles, movers, goals, objects and obstacles from above, for one world or a mosaic
  of many, with one Warp kernel launch per frame (torch ``uint8 [H, W, 3]`` on the device).
* :class:`CoilCurrentRenderer` draws the coils' currents of the magnetic model from above (:mod:`.coils`).
* :func:`save_png` writes a frame; :mod:`magwarp.record` writes videos.
* :class:`SyntheticScene` moves movers on a layout without the simulator (demos and tests).
"""

from magwarp.render.arrays import to_numpy_image
from magwarp.render.coils import CoilCurrentRenderer
from magwarp.render.io import save_png
from magwarp.render.synthetic import SyntheticScene
from magwarp.render.topdown import TopDownRenderer, object_parts

__all__ = ["TopDownRenderer", "CoilCurrentRenderer", "object_parts", "to_numpy_image", "save_png", "SyntheticScene"]
