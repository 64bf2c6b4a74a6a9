"""Env options as typed config dataclasses (the mjlab / Isaac Lab style): an env is built as
``Env(num_envs, config=None, *, device=..., seed=..., **options)``, where ``config`` is an instance of the env's
``config_type`` (a frozen dataclass that checks its own fields in ``__post_init__``) and ``options`` are any of its
fields, applied on top (``dataclasses.replace``). The same options as keywords and as a config give the same env;
a config can be built, inspected, stored and varied before any env exists::

    cfg = TrajectoryConfig(layout="B3", threshold_pos=0.05)
    env = TrajectoryPlanningEnv(4096, config=cfg, device="cuda:0")
    env2 = TrajectoryPlanningEnv(4096, config=cfg, v_max=1.5)   # the same config with one field changed

A subclass env with other defaults or more options has its own subclass of its parent's config type.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from magwarp.layout import MoverSpec, mover_params_kwargs


def resolve_config(env_type: type, config: Any, options: dict) -> Any:
    """``env_type``'s config (its ``config_type``) from ``config`` (an instance of it or None: its defaults) and
    keyword ``options`` (its field names) applied on top; a wrong config type or an unknown option raises a
    ``TypeError`` naming it (before anything is built)."""
    cls = env_type.config_type
    if config is not None and not isinstance(config, cls):
        raise TypeError(f"config of {env_type.__name__} must be a {cls.__name__}, got {type(config).__name__} "
                        f"({config!r})")
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(options) - fields)
    if unknown:
        raise TypeError(f"unknown {env_type.__name__} options {unknown}; {cls.__name__} has {sorted(fields)}")
    return dataclasses.replace(config, **options) if config is not None else cls(**options)


def make_mover_spec(collision_shape: str, collision_size, *, wall_margin: float, mover_params: dict | None,
                    **extra) -> MoverSpec:
    """The mover an env's options describe: MagBotSim's ``mover_params`` body (``{"size": half sizes, "mass": kg}``),
    the collision shape ``"circle"`` / ``"box"`` at ``collision_size`` (a radius, or box half sizes: one number or
    (2,); None: the mover's default), the wall margin, and any other :class:`~magwarp.layout.MoverSpec` field in
    ``extra`` (e.g. ``margin``, ``hover_gap``)."""
    kwargs: dict[str, Any] = dict(collision_shape=collision_shape, wall_margin=wall_margin, **extra,
                                  **mover_params_kwargs(mover_params))
    if collision_size is not None:
        if collision_shape == "circle":
            kwargs["collision_radius"] = float(collision_size)
        else:
            kwargs["collision_half_size"] = tuple(np.broadcast_to(np.asarray(collision_size, float), (2,)))
    return MoverSpec(**kwargs)
