"""The push envs' options as typed config dataclasses (magwarp.envs.push_config): defaults, checks before any build,
the config / keyword equivalence, the task subclasses' configs."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from magwarp.envs.coop_push import CoopPushConfig, CoopPushEnv
from magwarp.envs.coop_push_residual import CoopPushResidualConfig, CoopPushResidualEnv
from magwarp.envs.push import PushBoxEnv, PushEnv, PushLEnv, PushTEnv, PushXEnv
from magwarp.envs.push_config import PushBoxConfig, PushConfig, PushLConfig, PushTConfig, PushXConfig
from magwarp.envs.push_obstacles import PushWithObstaclesConfig, PushWithObstaclesEnv
from magwarp.envs.randomization import EventTerm, Uniform
from magwarp.layout import Layout
from magwarp.mjcf import ObstacleSpec

# PushEnv.__init__'s keyword defaults before the options became a config (its signature then, less num_envs, device,
# seed, render_mode, autoreset, check_inputs and nan_dump)
OLD_PUSH_DEFAULTS = {
    "object_type": "square_box", "layout": None, "num_movers": 1, "learn_pose": False, "learn_jerk": False,
    "learn_mover_c_rotation": False, "p_max_c": None, "v_max_c": 122.17305, "a_max_c": 122.17305,
    "j_max_c": 610.86524, "object_width": 0.06, "object_height": 0.06, "object_depth": 0.02,
    "object_segment_width": 0.02, "object_radius": 0.05, "object_mass": 0.3, "object_sliding_friction": 0.6,
    "object_torsional_friction": 0.0001, "object_ranges": None, "object_variants": 64, "std_noise": 0.0,
    "object_noise": 0.0, "v_max": 2.0, "a_max": 10.0, "j_max": 100.0, "num_cycles": 40, "physics_dt": 0.001,
    "max_position_err": 0.05, "min_coverage": 0.7, "use_sparse_pose_reward": False, "collision_penalty": -10.0,
    "per_step_penalty": -0.01, "object_at_goal_reward": 1.0, "early_termination_steps": None, "max_episode_steps": 25,
    "collision_shape": "circle", "collision_size": None, "collision_offset": 0.0, "collision_offset_wall": 0.0,
    "mover_params": None, "initial_mover_zpos": 0.003, "obstacles": (), "benchmark": None, "solver": "auto",
    "solver_iterations": 100, "ls_iterations": 50, "nconmax": None, "njmax": None, "randomization": None,
    "actuation": None, "sensors": None,
}


def _fields(cfg) -> dict:
    return {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)}


@pytest.fixture
def no_build(monkeypatch):
    """Any model build fails the test: the options must be refused before it."""
    def refuse(*args, **kwargs):
        raise AssertionError("a model was built")

    monkeypatch.setattr("magwarp.envs.push.MjwBackend", refuse)
    monkeypatch.setattr("magwarp.envs.push.generate_mjcf", refuse)


def test_defaults_are_the_old_constructor_defaults():
    assert _fields(PushConfig()) == OLD_PUSH_DEFAULTS
    assert PushEnv.config_type is PushConfig


def test_task_configs_carry_their_defaults():
    assert _fields(PushBoxConfig()) == OLD_PUSH_DEFAULTS  # Push-Box: a square box, position goals, 25 steps
    for cls, shape in ((PushTConfig, "t_shape"), (PushLConfig, "l_shape"), (PushXConfig, "plus_shape")):
        assert _fields(cls()) == {**OLD_PUSH_DEFAULTS, "object_type": shape, "learn_pose": True,
                                  "max_episode_steps": 50}
    for env_cls, cfg_cls in ((PushBoxEnv, PushBoxConfig), (PushTEnv, PushTConfig), (PushLEnv, PushLConfig),
                             (PushXEnv, PushXConfig), (PushWithObstaclesEnv, PushWithObstaclesConfig),
                             (CoopPushEnv, CoopPushConfig), (CoopPushResidualEnv, CoopPushResidualConfig)):
        assert env_cls.config_type is cfg_cls
    # the obstacle task: the values its constructor passed on, threshold_pos for max_position_err, walls of its mode
    obst = PushWithObstaclesConfig()
    assert (obst.obstacle_mode, obst.threshold_pos, obst.curriculum_episodes, obst.curriculum_success_rate) == (
        "simple", 0.05, 800, None)
    push = obst.as_push_config()
    assert type(push) is PushConfig
    assert _fields(push) == {**OLD_PUSH_DEFAULTS, "object_width": 0.035, "object_height": 0.035, "object_mass": 0.03,
                             "initial_mover_zpos": 0.002, "collision_penalty": -50.0, "per_step_penalty": -1.0,
                             "object_at_goal_reward": 0.0, "obstacles": push.obstacles}
    assert push.obstacles == (ObstacleSpec((0.48, 0.1), (0.03, 0.1, 0.03)),
                              ObstacleSpec((0.48, 0.62), (0.03, 0.1, 0.03)))
    hard = PushWithObstaclesConfig(obstacle_mode="hard", threshold_pos=0.07).as_push_config()
    assert hard.max_position_err == 0.07 and hard.obstacles[0].half_size[1] == 0.13
    # random, curriculum and mixed walls start simple
    assert PushWithObstaclesConfig(obstacle_mode={"hard": 1}).as_push_config().obstacles == push.obstacles
    # cooperative pushing: 2 movers, a 6 x 6 layout, 5 cm of box per mover, the heavy mass of force_ratio 1.5
    coop = CoopPushConfig()
    assert (coop.num_movers, coop.force_ratio, coop.max_episode_steps, coop.collision_shape, coop.collision_size) == (
        2, 1.5, 100, "box", 0.08)
    p = coop.as_push_config()
    assert p.layout.shape == (6, 6) and p.object_width == p.object_height == 0.1
    assert math.isclose(p.object_mass, 1.5 * 1.24 * 10.0 / (0.6 * 9.81))
    p4 = CoopPushConfig(num_movers=4, object_mass=2.0, object_height=0.12).as_push_config()
    assert (p4.object_width, p4.object_height, p4.object_mass) == (0.2, 0.12, 2.0)
    res = CoopPushResidualConfig()
    assert (res.residual_scale, res.baseline_options, res.num_movers) == (0.5, None, 2)
    assert set(_fields(res.as_push_config())) == set(OLD_PUSH_DEFAULTS)  # the residual's own fields left out


@pytest.mark.parametrize("options, error, message", [
    ({"min_coverage": 1.5}, ValueError, r"min_coverage must lie in \[0, 1\], got 1.5"),
    ({"max_position_err": 0.0}, ValueError, "max_position_err must be positive, got 0.0"),
    ({"per_step_penalty": float("nan")}, ValueError, "per_step_penalty must be finite"),
    ({"object_width": float("inf")}, ValueError, "object_width must be finite"),
    ({"nconmax": 0}, ValueError, "nconmax must be >= 1, got 0"),
    ({"njmax": 2.5}, ValueError, "njmax must be an integer"),
    ({"num_cycles": float("nan")}, ValueError, "num_cycles must be an integer"),
    ({"num_movers": 0}, ValueError, "num_movers must be >= 1, got 0"),
    ({"collision_shape": "hexagon"}, ValueError, "collision_shape must be 'circle' or 'box', got 'hexagon'"),
    ({"physics_dt": 0.004, "num_cycles": 50}, ValueError, "physics_dt=0.004 s does not divide the env step"),
    ({"std_noise": -1.0}, ValueError, "std_noise must be a non-negative number, got -1.0"),
    ({"object_noise": 1e7}, ValueError, "object_noise must be at most 1e"),
    ({"learn_pose": "yes"}, TypeError, "learn_pose must be True or False, got 'yes'"),
    ({"early_termination_steps": 0}, ValueError, "early_termination_steps must be >= 1"),
    ({"object_type": "hexagon"}, ValueError, "hexagon"),
    ({"benchmark": "B10"}, ValueError, "unknown pushing benchmark 'B10'"),
    ({"solver": "PGS"}, ValueError, "solver must be one of"),
    ({"object_ranges": {"colour": (1, 2)}}, ValueError, "unknown key 'colour'"),
    ({"object_ranges": {"width": (0.08, 0.05)}}, ValueError, "width"),
    ({"object_variants": 0}, ValueError, "object_variants must be >= 1, got 0"),
    ({"obstacles": [1]}, TypeError, "obstacles must be a tuple of ObstacleSpec"),
    ({"randomization": 3}, ValueError, "list of EventTerm"),
    ({"randomization": [EventTerm("object_width", Uniform(0.04, 0.06))], "object_ranges": {"width": (0.04, 0.06)}},
     ValueError, "not both object_ranges="),
    ({"sensors": {"pos_noise_std": 1e-3}, "std_noise": 1e-3}, ValueError, "give std_noise or sensors"),
    ({"sensors": {}, "learn_mover_c_rotation": True}, ValueError, "not with learn_mover_c_rotation=True"),
    ({"actuation": {"latency_cycles": 41}}, ValueError, "exceeds num_cycles=40"),
    ({"actuation": {"colour": 1}}, ValueError, "actuation has unknown option"),
    ({"layout": [[1, 1], [1]]}, ValueError, "layout must be a rectangular"),
])
def test_bad_options_are_refused_before_any_build(no_build, options, error, message):
    with pytest.raises(error, match=message):
        PushConfig(**options)
    with pytest.raises(error, match=message):
        PushEnv(1, device="cpu", **options)


def test_task_options_are_refused_before_any_build(no_build):
    with pytest.raises(ValueError, match="PushTEnv pushes a t_shape: object_type must be 't_shape', got 'box'"):
        PushTEnv(1, device="cpu", object_type="box")
    with pytest.raises(ValueError, match="PushBoxEnv pushes a square_box"):
        PushBoxConfig(object_type="cylinder")
    PushTConfig(object_type="T")  # an alias of its own shape
    with pytest.raises(ValueError, match="obstacle_mode"):
        PushWithObstaclesEnv(1, device="cpu", obstacle_mode="nightmare")
    with pytest.raises(ValueError, match=r"obstacle_mode\['hard'\] must be a finite weight"):
        PushWithObstaclesConfig(obstacle_mode={"hard": -1})
    with pytest.raises(ValueError, match="curriculum_episodes"):
        PushWithObstaclesConfig(obstacle_mode="curriculum", curriculum_episodes=0)
    with pytest.raises(ValueError, match="curriculum_success_rate needs obstacle_mode='curriculum', got 'hard'"):
        PushWithObstaclesConfig(obstacle_mode="hard", curriculum_success_rate=0.5)
    with pytest.raises(ValueError, match="give threshold_pos=0.1, not max_position_err"):
        PushWithObstaclesConfig(max_position_err=0.1)
    with pytest.raises(ValueError, match="max_position_err must be positive"):  # checked as the push option it is
        PushWithObstaclesConfig(threshold_pos=-0.1)
    with pytest.raises(ValueError, match="obstacles must stay empty"):
        PushWithObstaclesConfig(obstacles=(ObstacleSpec((0.2, 0.2)),))
    with pytest.raises(ValueError, match="PushWithObstaclesEnv pushes a square_box"):
        PushWithObstaclesConfig(object_type="t_shape")
    with pytest.raises(ValueError, match="num_movers=5"):
        CoopPushEnv(1, device="cpu", num_movers=5)
    with pytest.raises(ValueError, match="force_ratio must be positive"):
        CoopPushConfig(force_ratio=-1.0)
    with pytest.raises(ValueError, match="learn_mover_c_rotation=True is not supported"):
        CoopPushConfig(learn_mover_c_rotation=True)
    with pytest.raises(ValueError, match="residual_scale"):
        CoopPushResidualEnv(1, device="cpu", residual_scale=2.5)
    with pytest.raises(TypeError, match="baseline_options must be a dict"):
        CoopPushResidualConfig(baseline_options=[1.2])
    with pytest.raises(TypeError, match=r"unknown baseline_options \['bogus'\]"):
        CoopPushResidualEnv(1, device="cpu", baseline_options={"bogus": 1.0})
    with pytest.raises(ValueError, match="learn_jerk must be False"):
        CoopPushResidualConfig(learn_jerk=True)


def test_unknown_options_and_positional_values_are_type_errors(no_build):
    with pytest.raises(TypeError, match=r"unknown PushEnv options \['colour'\]; PushConfig has"):
        PushEnv(1, device="cpu", colour="red")
    with pytest.raises(TypeError, match=r"unknown PushTEnv options \['threshold_pos'\]"):
        PushTEnv(1, threshold_pos=0.1)
    with pytest.raises(TypeError, match="config of PushEnv must be a PushConfig, got str"):
        PushEnv(1, "t_shape")
    with pytest.raises(TypeError, match="config of CoopPushEnv must be a CoopPushConfig, got int"):
        CoopPushEnv(1, 2)
    with pytest.raises(TypeError, match="config of PushWithObstaclesEnv must be a PushWithObstaclesConfig, got str"):
        PushWithObstaclesEnv(1, "hard")
    with pytest.raises(TypeError, match="config of PushTEnv must be a PushTConfig, got PushConfig"):
        PushTEnv(1, PushConfig())
    with pytest.raises(TypeError):
        PushEnv(1, None, "cpu")  # device and the rest are keywords only


def test_replace_gives_a_checked_config():
    cfg = PushTConfig(min_coverage=0.9)
    other = dataclasses.replace(cfg, max_episode_steps=80, object_ranges={"width": (0.05, 0.07)})
    assert type(other) is PushTConfig and other.max_episode_steps == 80 and other.min_coverage == 0.9
    assert cfg.max_episode_steps == 50  # frozen: the original is unchanged
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.min_coverage = 0.5
    with pytest.raises(ValueError, match="min_coverage"):
        dataclasses.replace(cfg, min_coverage=-0.1)
    coop = dataclasses.replace(CoopPushConfig(), force_ratio=2.5)  # derived values follow the new fields
    assert math.isclose(coop.as_push_config().object_mass, 2.5 * 1.24 * 10.0 / (0.6 * 9.81))
    walls = dataclasses.replace(PushWithObstaclesConfig(), obstacle_mode="medium", threshold_pos=0.06)
    assert walls.as_push_config().max_position_err == 0.06 and walls.as_push_config().obstacles[0].xy == (0.48, 0.115)
    # derived pieces of a config, before any env
    assert PushConfig(benchmark="B3").mover_count() == 2 and PushConfig(num_movers=3).mover_count() == 3
    assert PushConfig().make_layout().shape == (4, 3)
    assert PushConfig(layout=np.ones((5, 4), np.int32)).make_layout().shape == (5, 4)
    assert isinstance(PushConfig(layout=Layout(np.ones((3, 3), np.int32))).make_layout(), Layout)
    assert PushConfig(physics_dt=0.002).substeps() == 20
    assert PushConfig(object_type="T").make_object().shape == "t_shape"
    assert PushConfig(object_ranges={"width": (0.04, 0.07), "mass": (0.2, 0.2)}).make_object().width == 0.07
    assert PushConfig(object_ranges={"width": (0.04, 0.07), "mass": (0.2, 0.2)}).varying_ranges() == {
        "width": (0.04, 0.07)}
    mover = PushConfig(collision_shape="box", collision_size=0.07).make_mover()
    assert mover.collision_half_size == (0.07, 0.07)
    control = PushConfig(learn_jerk=True, physics_dt=0.002).control_params()
    assert control.jerk and control.num_cycles == 20


def _first_obs(env):
    obs, _ = env.reset(seed=21)
    out = {k: v.clone() for k, v in obs.items()}
    obs, reward, *_ = env.step(torch.full((env.num_envs,) + env.single_action_space.shape, 0.5))
    return out, obs, reward


def test_a_config_and_the_same_keywords_give_the_same_env():
    options = dict(object_type="box", object_width=0.05, object_height=0.03, max_episode_steps=30, std_noise=1e-3,
                   collision_offset=0.01)
    by_keywords = PushEnv(2, device="cpu", seed=5, **options)
    cfg = PushConfig(**options)
    by_config = PushEnv(2, cfg, device="cpu", seed=5)
    mixed = PushEnv(2, PushConfig(object_type="box", object_width=0.05), device="cpu", seed=5,
                    **{k: v for k, v in options.items() if k not in ("object_type", "object_width")})
    assert by_config.config == cfg
    assert by_keywords.config == cfg and mixed.config == cfg
    first = _first_obs(by_keywords)
    for env in (by_config, mixed):
        assert env.single_observation_space == by_keywords.single_observation_space
        assert env.single_action_space == by_keywords.single_action_space
        assert env.max_episode_steps == 30 and env.object.shape == "box" and env.collision_offset == 0.01
        other = _first_obs(env)
        for a, b in zip(first[:2], other[:2]):
            for key in a:
                assert torch.equal(a[key], b[key]), key
        assert torch.equal(first[2], other[2])


def test_task_envs_keep_their_config():
    env = PushTEnv(1, device="cpu", seed=0)
    assert type(env.config) is PushTConfig and env.config.object_type == "t_shape"
    assert env.learn_pose and env.max_episode_steps == 50 and env.object.shape == "t_shape"
    walls = PushWithObstaclesEnv(1, device="cpu", seed=0, obstacle_mode="hard", threshold_pos=0.07)
    assert type(walls.config) is PushWithObstaclesConfig and walls.config.obstacle_mode == "hard"
    assert walls.max_position_err == 0.07 and walls.obstacle_mode == "hard" and walls.collision_penalty == -50.0
    assert torch.allclose(walls.obstacle_boxes[0, :, 3], torch.tensor([0.13, 0.13]))
    coop = CoopPushEnv(1, CoopPushConfig(num_movers=3), device="cpu", seed=0)
    assert coop.num_movers == 3 and coop.layout.shape == (6, 6) and coop.object.width == pytest.approx(0.15)
    assert coop.movers_needed == 2 and coop.friction_force == pytest.approx(1.5 * coop.mover_force)


def test_array_layouts_are_kept_as_layouts_and_compare_by_value():
    """A 0/1 array layout is checked and stored as a Layout, so two configs of the same options compare equal (the
    swarm config does the same)."""
    from magwarp.layout import Layout
    from magwarp.swarm import SwarmConfig

    tiles = np.ones((4, 3), dtype=np.int32)
    tiles[0, 0] = 0
    a, b = PushConfig(layout=tiles), PushConfig(layout=tiles.copy())
    assert isinstance(a.layout, Layout) and a == b and a != PushConfig(layout=np.ones((4, 3)))
    s = SwarmConfig(layout=tiles)
    assert isinstance(s.layout, Layout) and s == SwarmConfig(layout=tiles.copy())
