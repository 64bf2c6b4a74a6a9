"""TrajectoryPlanningEnv's options as a config dataclass (magwarp.envs.trajectory_config): the same env from a
config, from keywords and from both; every bad option raises naming it before anything is built."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from magwarp.envs.trajectory import TrajectoryPlanningEnv
from magwarp.envs.trajectory_config import TrajectoryConfig, per_mover_sizes
from magwarp.layout import Layout, LayoutError


def test_defaults_are_magbotsims_benchmark_b0():
    cfg = TrajectoryConfig()
    assert (cfg.layout, cfg.num_movers, cfg.movers) == ("B0", None, 3)
    assert (cfg.v_max, cfg.a_max, cfg.j_max, cfg.num_cycles) == (2.0, 10.0, 100.0, 40)
    rewards = (cfg.reward_success, cfg.reward_collision, cfg.reward_per_step)
    assert cfg.threshold_pos == 0.1 and rewards == (20.0, -20.0, -1.0)
    assert (cfg.timeout_steps, cfg.max_episode_steps, cfg.std_noise) == (50, None, 0.0)
    assert cfg.fused and cfg.graph and not cfg.learn_jerk


def test_config_keywords_and_both_build_the_same_env():
    """A config, the same options as keywords, and a config with keywords on top give equal configs and the same
    first observation for the same seed."""
    cfg = TrajectoryConfig(layout="B3", threshold_pos=0.05, num_cycles=8)
    envs = [TrajectoryPlanningEnv(3, config=cfg, device="cpu", seed=5),
            TrajectoryPlanningEnv(3, "B3", threshold_pos=0.05, num_cycles=8, device="cpu", seed=5),
            TrajectoryPlanningEnv(3, config=TrajectoryConfig(layout="B3"), threshold_pos=0.05, num_cycles=8,
                                  device="cpu", seed=5)]
    assert envs[0].config == envs[1].config == envs[2].config
    obs = [e.reset(seed=11)[0] for e in envs]
    for o in obs[1:]:
        for key in o:
            assert torch.equal(o[key], obs[0][key]), key
    assert envs[0].threshold_pos == 0.05 and envs[0].num_cycles == 8 and envs[0].num_movers == cfg.movers


def test_positional_layout_and_movers_go_on_top_of_the_config():
    tiles = np.ones((4, 5), dtype=np.int32)
    env = TrajectoryPlanningEnv(2, tiles, 2, config=TrajectoryConfig(layout="B5", v_max=1.0), device="cpu", seed=0)
    assert env.num_movers == 2 and env.layout_name == "custom" and env.config.v_max == 1.0
    assert isinstance(env.config.layout, Layout) and np.array_equal(env.config.layout.tiles, tiles)


def test_replace_and_frozen():
    cfg = TrajectoryConfig(collision_shape="box", collision_size=np.array([0.05, 0.06]))
    assert cfg.collision_size == (0.05, 0.06)  # an array is stored as tuples
    again = dataclasses.replace(cfg, a_max=5.0)
    assert again.a_max == 5.0 and again.collision_size == cfg.collision_size
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.a_max = 1.0
    with pytest.raises(ValueError, match="a_max must be finite"):
        dataclasses.replace(cfg, a_max=float("inf"))


@pytest.mark.parametrize("options, error, message", [
    ({"v_max": float("nan")}, ValueError, "v_max must be finite"),
    ({"num_cycles": 0}, ValueError, "num_cycles must be >= 1, got 0"),
    ({"num_cycles": 2.5}, ValueError, "num_cycles must be an integer >= 1, got 2.5"),
    ({"fused": "yes"}, TypeError, "fused must be True or False, got 'yes'"),
    ({"timeout_steps": -1}, ValueError, "timeout_steps must be >= 1, got -1"),
    ({"layout": "B42"}, LayoutError, "unknown benchmark layout 'B42'"),
    ({"layout": [[1, 1], [1, 1]]}, ValueError, "num_movers must be a positive integer for a custom layout"),
    ({"num_movers": 0}, ValueError, "num_movers must be >= 1, got 0"),
    ({"collision_shape": "tri"}, ValueError, "collision_shape must be 'circle' or 'box', got 'tri'"),
    ({"threshold_pos": 0.0}, ValueError, "threshold_pos must be positive, got 0.0"),
    ({"max_episode_steps": 0}, ValueError, "max_episode_steps must be None or an integer >= 1, got 0"),
    ({"std_noise": -0.1}, ValueError, "std_noise must be a non-negative number, got -0.1"),
    ({"std_noise": 0.01, "sensors": {"pos_noise_std": 0.01}}, ValueError, "give std_noise or sensors, not both"),
    ({"collision_size": [0.1, 0.2]}, ValueError, r"collision_size for a circle must be a positive radius"),
    ({"collision_shape": "box", "collision_size": -0.1}, ValueError, "collision_size for a box must be a positive"),
])
def test_bad_options_raise_naming_the_value(options, error, message):
    with pytest.raises(error, match=message):
        TrajectoryConfig(**options)
    with pytest.raises(error, match=message):  # the env raises the same, before building anything
        TrajectoryPlanningEnv(2, device="cpu", **options)


def test_unknown_option_and_wrong_config_type():
    with pytest.raises(TypeError, match=r"unknown TrajectoryPlanningEnv options \['vmax'\]"):
        TrajectoryPlanningEnv(2, device="cpu", vmax=1.0)
    with pytest.raises(TypeError, match="config of TrajectoryPlanningEnv must be a TrajectoryConfig, got dict"):
        TrajectoryPlanningEnv(2, config={"layout": "B0"}, device="cpu")


def test_per_mover_sizes_and_the_built_mover():
    radii, halves = per_mover_sizes("circle", [0.05, 0.07, 0.06], 3)
    assert halves is None and np.array_equal(radii, [0.05, 0.07, 0.06])
    radii, halves = per_mover_sizes("box", (0.05, 0.04), 2)
    assert radii is None and np.array_equal(halves, [[0.05, 0.04], [0.05, 0.04]])
    cfg = TrajectoryConfig(collision_size=[0.05, 0.07, 0.06], safety_margin=0.01, collision_offset_wall=0.002)
    mover = cfg.make_mover()
    assert mover.collision_radius == pytest.approx(0.07) and mover.margin == 0.01 and mover.wall_margin == 0.002


def test_configs_with_array_layouts_compare_by_value():
    """A layout given as an array is stored as a Layout, compared (and hashed) by its tile map and tile spec."""
    holes = np.ones((4, 5), dtype=np.int32)
    holes[1, 2] = 0
    a, b = (TrajectoryConfig(layout=holes.copy(), num_movers=2) for _ in range(2))
    assert a == b and hash(a.layout) == hash(b.layout)
    assert a != TrajectoryConfig(layout=np.ones((4, 5)), num_movers=2)
    assert a != dataclasses.replace(a, layout=Layout(holes, tile=dataclasses.replace(a.layout.tile, size=0.2)))
    assert Layout(holes) != "B0" and len({Layout(holes), Layout(holes.copy()), Layout(np.ones((4, 5)))}) == 2
