"""LevitationEnv's options as a config dataclass (magwarp.envs.levitation_config): the same env from a config and
from keywords; every bad option raises naming it before the magnetic model or the simulator is built."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from magwarp.envs.levitation import LevitationEnv
from magwarp.envs.levitation_config import LevitationConfig
from magwarp.envs.levitation_residual import LevitationResidualConfig, LevitationResidualEnv


def test_defaults_and_normal_form():
    cfg = LevitationConfig()
    assert (cfg.task, cfg.action, cfg.tiles, cfg.dt, cfg.num_cycles, cfg.max_episode_steps) == (
        "setpoint", "currents", (2, 2), 2.5e-4, 4, 500)
    assert cfg.setpoint_gap == (0.003, 0.005) and cfg.fail_gap == (0.001, 0.007)
    cfg = LevitationConfig(tiles=[3, 2], wrench_scale=[30, 1], setpoint_gap=[0.0035, 0.0045])
    assert cfg.tiles == (3, 2) and cfg.wrench_scale == (30.0, 1.0) and cfg.setpoint_gap == (0.0035, 0.0045)
    residual = LevitationResidualConfig()
    assert residual.action == "wrench" and residual.residual_scale == 0.25 and residual.pd_frequency == 15.0


@pytest.mark.parametrize("options, error, message", [
    ({"action": "torque"}, ValueError, "action must be 'currents' or 'wrench', got 'torque'"),
    ({"task": "lift"}, ValueError, "task must be one of .*got 'lift'"),
    ({"dt": 0.0}, ValueError, r"dt must be a finite number in \(0.0, 0.01\], got 0.0"),
    ({"pos_scale": float("nan")}, ValueError, "pos_scale must be a finite number"),
    ({"setpoint_gap": (0.003, 0.009)}, ValueError, r"setpoint_gap \(0.003, 0.009\) must lie inside fail_gap"),
    ({"fail_gap": (0.001,)}, ValueError, "fail_gap must be two numbers"),
    ({"success_tol": (0.0, 0.1)}, ValueError, r"success_tol must be two numbers in \(0, 1\]"),
    ({"wrench_scale": (40.0, -1.0)}, ValueError, r"wrench_scale must be two numbers in \(0, 1e6\]"),
    ({"tiles": (2, 0)}, ValueError, "tiles must be >= 1, got 0"),
    ({"tiles": (2, 2, 2)}, ValueError, "tiles must be two positive integers"),
    ({"tiles": "22"}, TypeError, "tiles must be two positive integers"),
    ({"num_cycles": 0}, ValueError, "num_cycles must be >= 1, got 0"),
    ({"magnetics": "default"}, TypeError, "magnetics must be a MagneticModel, got str"),
])
def test_bad_options_raise_naming_the_value(options, error, message):
    with pytest.raises(error, match=message):
        LevitationConfig(**options)
    with pytest.raises(error, match=message):
        LevitationEnv(1, device="cpu", **options)


def test_residual_options_are_checked_before_the_build():
    with pytest.raises(ValueError, match="residual_scale"):
        LevitationResidualConfig(residual_scale=0.0)
    with pytest.raises(TypeError, match=r"unknown LevitationResidualEnv options \['scale'\]"):
        LevitationResidualEnv(1, device="cpu", scale=0.5)
    with pytest.raises(TypeError, match="config of LevitationEnv must be a LevitationConfig, got dict"):
        LevitationEnv(1, {"task": "hover"}, device="cpu")


def test_config_and_keywords_build_the_same_env():
    cfg = LevitationConfig(task="hover", num_cycles=2, max_episode_steps=20)
    a = LevitationEnv(2, cfg, device="cpu", seed=3)
    b = LevitationEnv(2, device="cpu", seed=3, task="hover", num_cycles=2, max_episode_steps=20)
    c = LevitationEnv(2, dataclasses.replace(cfg, num_cycles=3), device="cpu", seed=3, num_cycles=2)
    assert a.config == b.config == c.config
    obs = [e.reset(seed=5)[0] for e in (a, b, c)]
    action = torch.zeros((2, a.single_action_space.shape[0]))
    steps = [e.step(action)[0] for e in (a, b, c)]
    for o, s in zip(obs[1:], steps[1:]):
        assert torch.equal(o, obs[0]) and torch.equal(s, steps[0])
    assert a.num_cycles == 2 and a.task == "hover" and a.max_episode_steps == 20
