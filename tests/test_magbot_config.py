"""The MagBot envs' typed options (:class:`magwarp.envs.magbot_task.MagBotConfig` and its per-env subclasses): checks
that name the bad value, building from a config, a dict and keyword options, and that a config object gives the
same env, to the bit, as the equivalent keyword options (and gymnasium.make with them)."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest
import torch
import warp as wp

import magwarp  # noqa: F401  (registers the env ids)
from magwarp.envs.gripper_pick_place import GripperPickPlaceConfig, GripperPickPlaceEnv
from magwarp.envs.magbot_task import MagBotConfig
from magwarp.envs.platform_pick_place import PICK_PLACE_PLATFORM, PlatformPickPlaceConfig, PlatformPickPlaceEnv
from magwarp.envs.platform_pose import PlatformPoseConfig, PlatformPoseEnv
from magwarp.magbots.control import TrackingGains
from magwarp.magbots.mjcf import PlatformModelSpec
from magwarp.mjcf import ObjectSpec

wp.config.quiet = True

CONFIGS = (MagBotConfig, PlatformPoseConfig, PlatformPickPlaceConfig, GripperPickPlaceConfig)


def test_defaults_are_the_envs_defaults():
    pose, pick, grip = PlatformPoseConfig(), PlatformPickPlaceConfig(), GripperPickPlaceConfig()
    assert (pose.max_episode_steps, pick.max_episode_steps, grip.max_episode_steps) == (50, 300, 200)
    assert (pose.per_step_penalty, pick.per_step_penalty, grip.per_step_penalty) == (-0.01, -0.001, -0.01)
    assert pose.model == PlatformModelSpec() and pick.model is PICK_PLACE_PLATFORM
    assert grip.gains == TrackingGains() and grip.obj.shape == "square_box" and grip.obj.width == 0.02
    assert pose.pose_step == (0.02, 0.02, 0.01, 0.02, 0.02, 0.1)
    # None (the old keyword default) gives the default option objects
    assert PlatformPickPlaceConfig(model=None, gains=None).model is PICK_PLACE_PLATFORM
    assert PlatformPoseConfig(geometry=None, model=None) == pose


def test_values_are_stored_converted():
    cfg = PlatformPoseConfig(num_cycles=20.0, v_max=3, pose_step=[0.1] * 6, success_reward=np.float32(2.0))
    assert type(cfg.num_cycles) is int and cfg.num_cycles == 20
    assert type(cfg.v_max) is float and type(cfg.success_reward) is float
    assert cfg.pose_step == (0.1,) * 6 and all(type(v) is float for v in cfg.pose_step)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.v_max = 1.0


@pytest.mark.parametrize("cls, options, exc, message", [
    (PlatformPoseConfig, {"action_mode": "joint"}, ValueError,
     r"action_mode must be one of \('mover', 'pose'\), got 'joint'"),
    (GripperPickPlaceConfig, {"action_mode": "pose"}, ValueError, r"got 'pose'"),
    (PlatformPoseConfig, {"num_cycles": 2.5}, ValueError, r"num_cycles must be an integer >= 1, got 2.5"),
    (PlatformPoseConfig, {"max_episode_steps": 0}, ValueError, r"max_episode_steps must be >= 1, got 0"),
    (PlatformPoseConfig, {"position_tolerance": -0.1}, ValueError,
     r"position_tolerance must be a positive number, got -0.1"),
    (PlatformPoseConfig, {"a_max_c": float("inf")}, ValueError, r"a_max_c must be a finite number, got inf"),
    (PlatformPoseConfig, {"v_max": 1e9}, ValueError, r"v_max must be at most 1e\+06"),
    (PlatformPoseConfig, {"sample_margin": 1.0}, ValueError, r"sample_margin must lie in \[0, 1\), got 1.0"),
    (PlatformPoseConfig, {"pose_step": (0.1, 0.1)}, ValueError,
     r"pose_step must be six positive numbers .* got \(0.1, 0.1\)"),
    (PlatformPoseConfig, {"pose_step": (0.1,) * 5 + (0.0,)}, ValueError, r"pose_step must be six positive"),
    (PlatformPoseConfig, {"gains": {"kp": 1.0}}, TypeError,
     r"gains must be a TrackingGains \(or None\), got \{'kp': 1.0\}"),
    (PlatformPoseConfig, {"model": "big"}, TypeError, r"model must be a PlatformModelSpec \(or None\), got 'big'"),
    (PlatformPickPlaceConfig, {"products": 0}, ValueError, r"products must be >= 1, got 0"),
    (PlatformPickPlaceConfig, {"product_jitter": (0.01, -1.0, 0.0)}, ValueError,
     r"product_jitter must be three non-negative numbers \(x, y, yaw\), got \(0.01, -1.0, 0.0\)"),
    (PlatformPickPlaceConfig, {"start_height": 0.0}, ValueError, r"start_height must be a positive number, got 0.0"),
    (PlatformPickPlaceConfig, {"scene": 3}, TypeError, r"scene must be a PickPlaceScene \(or None\), got 3"),
    (GripperPickPlaceConfig, {"gripper_step": (0.1, 0.1)}, ValueError, r"gripper_step must be four positive numbers"),
    (GripperPickPlaceConfig, {"gripper_step": (0.1, float("nan"), 0.1, 0.1)}, ValueError,
     r"gripper_step must be finite"),
    (GripperPickPlaceConfig, {"jaw_squeeze": "hard"}, TypeError, r"jaw_squeeze must be a finite number, got 'hard'"),
    (GripperPickPlaceConfig, {"obj": ObjectSpec(shape="cylinder")}, ValueError, r"obj must be a square_box ObjectSpec"),
    (GripperPickPlaceConfig, {"obj": ObjectSpec(shape="square_box", width=0.1)}, ValueError,
     r"the object \(width 0.2 m\) must fit the jaw"),
])
def test_bad_values_are_refused_naming_them(cls, options, exc, message):
    with pytest.raises(exc, match=message):
        cls(**options)
    with pytest.raises(exc, match=message):  # the same through build (the envs' keyword options)
        cls.build(None, **options)


def test_build_merges_config_dict_and_options():
    base = PlatformPoseConfig(max_episode_steps=9, action_mode="pose")
    assert PlatformPoseConfig.build() == PlatformPoseConfig()
    assert PlatformPoseConfig.build(base) is base
    merged = PlatformPoseConfig.build(base, max_episode_steps=4)
    assert (merged.max_episode_steps, merged.action_mode) == (4, "pose") and base.max_episode_steps == 9
    from_dict = PlatformPoseConfig.build({"action_mode": "pose", "max_episode_steps": 9})
    assert from_dict == base
    assert PlatformPoseConfig.build({"max_episode_steps": 9}, max_episode_steps=3).max_episode_steps == 3
    with pytest.raises(TypeError, match=r"unknown PlatformPoseConfig option\(s\) 'products' \(the options: "):
        PlatformPoseConfig.build(base, products=2)
    with pytest.raises(TypeError, match=r"unknown GripperPickPlaceConfig option\(s\) 'pose_step'"):
        GripperPickPlaceConfig.build({"pose_step": (0.1,) * 6})
    with pytest.raises(TypeError, match=r"config must be a PlatformPickPlaceConfig, a dict of its fields or None, got "
                                        r"PlatformPoseConfig\("):
        PlatformPickPlaceConfig.build(PlatformPoseConfig())
    for options in ({"sample_margin": 0.1}, {"position_tolerance": 0.1}):
        with pytest.raises(ValueError, match="PlatformPickPlace has no pose goals"):
            PlatformPickPlaceConfig.build(None, **options)
        with pytest.raises(ValueError, match="PlatformPickPlace has no pose goals"):
            PlatformPickPlaceConfig.build(options)


def test_every_config_field_is_an_env_keyword_of_its_class():
    for env_cls, cfg_cls in ((PlatformPoseEnv, PlatformPoseConfig), (PlatformPickPlaceEnv, PlatformPickPlaceConfig),
                             (GripperPickPlaceEnv, GripperPickPlaceConfig)):
        assert env_cls.config_class is cfg_cls
    assert {f.name for f in dataclasses.fields(MagBotConfig)} <= {f.name for f in dataclasses.fields(
        GripperPickPlaceConfig)}


def _first_steps(env, steps: int = 3):
    """The reset and ``steps`` steps of seeded random actions."""
    obs, _ = env.reset(seed=3)
    gen = torch.Generator().manual_seed(7)
    high = torch.as_tensor(env.action_space.high)
    out = [obs]
    for _ in range(steps):
        action = ((2 * torch.rand(env.action_space.shape, generator=gen) - 1) * high).float()
        obs, reward, terminated, truncated, info = env.step(action)
        out.append((obs, reward, terminated, truncated, {k: v for k, v in info.items() if torch.is_tensor(v)}))
    return out


def _assert_identical(a, b, path="out"):
    if torch.is_tensor(a):
        assert torch.equal(a, b), path
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _assert_identical(a[k], b[k], f"{path}[{k!r}]")
    else:
        assert len(a) == len(b), path
        for i, (u, v) in enumerate(zip(a, b)):
            _assert_identical(u, v, f"{path}[{i}]")


@pytest.mark.parametrize("env_cls, options", [
    (PlatformPoseEnv, {"action_mode": "pose", "pose_step": (0.03, 0.02, 0.01, 0.02, 0.02, 0.1), "sample_margin": 0.3,
                       "max_episode_steps": 2, "gains": TrackingGains(kp=30.0)}),
    (PlatformPickPlaceEnv, {"action_mode": "pose", "products": 2, "start_yaw": 0.1, "drop_penalty": -2.0}),
    (GripperPickPlaceEnv, {"action_mode": "gripper", "jaw_squeeze": 4.0, "min_distance": 0.2,
                           "max_episode_steps": 2}),
])
def test_config_and_keywords_give_bit_identical_first_steps(env_cls, options):
    cfg = env_cls.config_class(**options)
    by_config = env_cls(2, device="cpu", seed=3, config=cfg)
    by_keywords = env_cls(2, device="cpu", seed=3, **options)
    assert by_config.config == by_keywords.config == cfg
    for name in ("action_mode", "max_episode_steps", "per_step_penalty", "gains"):
        assert getattr(by_keywords, name) == getattr(cfg, name)
    _assert_identical(_first_steps(by_config), _first_steps(by_keywords))


def test_gym_make_takes_a_config_or_its_keywords():
    cfg = GripperPickPlaceConfig(max_episode_steps=3, action_mode="gripper")
    env = gym.make_vec("magwarp/GripperPickPlace-v0", num_envs=1, device="cpu", config=cfg)
    assert env.config is cfg and env.max_episode_steps == 3
    single = gym.make("magwarp/GripperPickPlace-v0", device="cpu", config={"max_episode_steps": 3},
                      action_mode="gripper")
    assert single.unwrapped.vec.config == cfg
    with pytest.raises(TypeError, match=r"unknown GripperPickPlaceConfig option\(s\) 'gripper_steps'"):
        gym.make_vec("magwarp/GripperPickPlace-v0", num_envs=1, device="cpu", gripper_steps=(0.1,) * 4)
