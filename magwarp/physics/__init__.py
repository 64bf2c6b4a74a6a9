"""mujoco-warp backend for contact-rich tasks (object pushing): batched stepping, mover control, task math."""

from magwarp.physics.backend import ControlParams, MjwBackend, PhysicsInputError

__all__ = ["ControlParams", "MjwBackend", "PhysicsInputError"]
