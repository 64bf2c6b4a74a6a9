"""mujoco-warp backend for contact-rich tasks (object pushing): batched stepping, mover control, task math."""

from magwarp.physics.backend import ControlParams, MjwBackend, PhysicsInputError
from magwarp.physics.contacts import ContactFlags
from magwarp.physics.coverage import coverage, shape_parts

__all__ = ["ContactFlags", "ControlParams", "MjwBackend", "PhysicsInputError", "coverage", "shape_parts"]
