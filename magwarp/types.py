"""Typed containers: :class:`Model` (static, per-mover parameters broadcast over worlds) and :class:`State` (batched
structure-of-arrays, shape ``(num_worlds, num_movers)`` per field), plus the small Warp structs kernels take.

Every field is a Warp array on the simulator's device; torch sees them zero-copy through ``wp.to_torch``.
"""

from __future__ import annotations

from dataclasses import dataclass

import warp as wp

SHAPE_CIRCLE = 0
SHAPE_BOX = 1

#: x/y position, velocity and drive acceleration of one mover in float64 (x, y, vx, vy, ax, ay): the planar law's
#: own state, so that x/y motion follows MagBotSim's (float64 MuJoCo) to float32 rounding over seconds
Planar64 = wp.types.vector(length=6, dtype=wp.float64)

# Bits of the per-mover collision flags.
COLLIDE_MOVER = 1
COLLIDE_WALL = 2


@wp.struct
class Limits:
    """x/y motion limits and command mode (MagBotSim: 2 m/s, 10 m/s^2, 100 m/s^3)."""

    dt: float
    v_max: float
    a_max: float
    j_max: float
    jerk_mode: int  # 0: commands are accelerations, 1: commands are jerks
    gravity: float  # magnitude of gravity along -z (9.81)
    # The same four limits in float64, for the x/y law (float32 holds 0.001 s as 1.0000000475e-3 s, which would
    # stretch every x/y step by 5e-8 of itself)
    dt64: wp.float64
    v_max64: wp.float64
    a_max64: wp.float64
    j_max64: wp.float64


@wp.struct
class Impedance:
    """Impedance gains for the held axes: the law is ``K * error - D * velocity`` with ``D = 2 sqrt(K M)``."""

    k_lin: wp.vec3
    k_rot: wp.vec3
    mask_lin: wp.vec3  # 1 for axes the controller holds (default z only)
    mask_rot: wp.vec3  # default roll, pitch, yaw


@wp.struct
class Body:
    """Parameters of one mover in one world (the model's ``body`` array is ``[num_worlds, num_movers]``: domain
    randomisation, :mod:`magwarp.envs.randomization`, rewrites rows on the device): rigid body, impedance gains and x/y
    limits. Built with every row at the simulator's configured values."""

    mass: float  # true mass (mover plus payload)
    inv_mass: float  # 1 / mass, so that the integrator multiplies instead of dividing every cycle
    inertia: wp.vec3  # principal moments in the body frame
    damp_lin: wp.vec3  # critical damping of the impedance hold, 2 sqrt(K m), per world axis
    damp_rot: wp.vec3  # 2 sqrt(K I) per axis, with the principal inertia (not the mass, as MagBotSim does)
    k_lin: wp.vec3  # impedance stiffness (the force model sees it as ``Impedance.k_lin``)
    k_rot: wp.vec3
    drive_gain: wp.float64  # x/y acceleration per commanded one: the controller's mass / the true mass (1 nominal)
    com: wp.vec3  # centre of mass in the body frame, from the mover centre (a payload's offset; 0 nominal)
    v_max: wp.float64  # x/y limits of this mover (float64, as the x/y law runs)
    a_max: wp.float64
    j_max: wp.float64


@wp.struct
class Pose:
    """Kinematic state of one mover (world frame velocities)."""

    pos: wp.vec3
    quat: wp.quat
    vel: wp.vec3
    omega: wp.vec3


@wp.func
def make_pose(pos: wp.vec3, quat: wp.quat, vel: wp.vec3, omega: wp.vec3) -> Pose:
    """A :class:`Pose` from its four parts (kernels read them from separate state arrays)."""
    p = Pose()
    p.pos = pos
    p.quat = quat
    p.vel = vel
    p.omega = omega
    return p


@wp.struct
class Wrench:
    force: wp.vec3
    torque: wp.vec3


@wp.struct
class Collision:
    """Collision-check parameters shared by all worlds."""

    shape: int  # SHAPE_CIRCLE or SHAPE_BOX
    margin: float  # added to every collision shape for mover-mover checks
    wall_margin: float  # added to the footprint for wall checks
    tile_size: float
    stop_on_collision: int  # 1: a world stops integrating for the rest of the step after its first collision
    full_rect: int  # 1 when every tile of the layout is present: the wall check is then four comparisons
    extent: wp.vec2  # the layout's size (m), used when full_rect is 1


@wp.struct
class Grid:
    """Uniform binning grid for mover-mover broad phase, one block of cells per world."""

    cell_size: float
    ncx: int
    ncy: int


@dataclass
class Model:
    """Parameters. Per-mover arrays are ``[num_worlds, num_movers]`` (filled with the configured values; domain
    randomisation changes rows on the device, no rebuild), structs are shared by all worlds."""

    num_worlds: int
    num_movers: int
    device: wp.context.Device
    limits: Limits
    impedance: Impedance
    collision: Collision
    grid: Grid
    tiles: wp.array2d  # int32 (nx, ny), 1 = tile present
    body: wp.array2d  # Body per world and mover
    radius: wp.array2d  # float32 per world and mover, circle collision radius
    half_size: wp.array2d  # vec2 per world and mover, box collision half extents
    margins: wp.array  # vec2 per world: (mover-mover margin, wall margin); Collision holds the configured ones
    hover_z: float


@dataclass
class State:
    """Batched simulation state; all fields have shape ``(num_worlds, num_movers)`` unless noted."""

    pos: wp.array2d  # vec3, mover centre (m)
    quat: wp.array2d  # quat (x, y, z, w)
    vel: wp.array2d  # vec3, linear velocity (m/s)
    omega: wp.array2d  # vec3, angular velocity in the world frame (rad/s)
    acc: wp.array2d  # vec2, x/y drive acceleration of the last cycle (m/s^2), the state jerk commands integrate
    cmd: wp.array2d  # vec2, command (acceleration or jerk, by Limits.jerk_mode)
    target_pos: wp.array2d  # vec3, impedance target position (only held axes matter)
    target_quat: wp.array2d  # quat, impedance target orientation (yaw target)
    wall: wp.array2d  # int32, 1 when the footprint left the tiles in the last cycle
    flags: wp.array2d  # int32, COLLIDE_* bits of the last cycle
    flags_any: wp.array2d  # int32, COLLIDE_* bits OR-ed over the cycles of the current step
    partner: wp.array2d  # int32, lowest index of a mover colliding with this one in the last cycle, -1 if none
    world_pairs: wp.array  # int32 (num_worlds,), colliding pairs in the last cycle
    pair_list: wp.array2d  # vec2i (num_worlds, max_pairs): the colliding pairs (i < j) of the last cycle; the first
    # min(world_pairs, max_pairs) rows are valid, in no particular order on a GPU
    world_walls: wp.array  # int32 (num_worlds,), movers off the tiles in the last cycle
    halted: wp.array  # int32 (num_worlds,), 1 once the world collided in the current step (stop_on_collision)
    cycles: wp.array  # int32 (num_worlds,), cycles integrated in the current step
    force_aux: wp.array3d  # float32 (num_worlds, num_movers, K), free inputs for custom force models
    planar: wp.array2d  # Planar64: x/y position, velocity, acceleration in float64; pos/vel/acc are its rounding.
    # A write into pos, vel or acc (a reset, a user's edit) is picked up: where the float32 field no longer equals
    # the rounding of this state, the kernels restart it from the float32 value.
