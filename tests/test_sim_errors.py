"""Bad inputs raise clear errors that name the bad value, and a rejected input leaves the state untouched."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp.layout import Layout, LayoutError, MoverSpec
from magwarp.sim import Simulator

L3 = Layout.grid(3, 3)


def state_copy(sim):
    return {k: getattr(sim, k).clone() for k in ("pos", "quat", "vel", "omega", "acc", "cmd", "flags", "cycles")}


def assert_state_equal(a, b):
    for k in a:
        assert torch.equal(a[k], b[k]), f"{k} changed by a rejected input"


@pytest.fixture
def sim():
    s = Simulator(L3, num_movers=3, num_worlds=2, device="cpu")
    s.step(5, cmd=torch.ones(2, 3, 2))
    return s


# ---------------------------------------------------------------------------------------------- layouts
@pytest.mark.parametrize(
    "tiles, match",
    [
        (np.zeros((0, 3)), r"empty.*\(0, 3\)"),
        (np.zeros((3, 3), dtype=int), "no tiles"),
        (np.array([[1, 2], [1, 1]]), r"only 0 and 1.*2"),
        (np.array([[1, 0.5], [1, 1]]), r"only 0 and 1.*0\.5"),
        (np.array([[1, np.nan], [1, 1]]), r"only 0 and 1.*nan"),
        (np.array([[1, -1], [1, 1]]), r"only 0 and 1.*-1"),
        (np.array([1, 1, 1]), r"2-D.*\(3,\)"),
        (np.ones((2, 2, 2)), r"2-D.*\(2, 2, 2\)"),
        (np.array([["a", "b"]]), "only 0 and 1"),
    ],
)
def test_bad_layouts(tiles, match):
    with pytest.raises(LayoutError, match=match):
        Layout(tiles)
    with pytest.raises(LayoutError, match=match):  # the simulator accepts raw arrays, validated the same way
        Simulator(tiles, num_movers=1, device="cpu")


def test_bool_layout_is_accepted():
    assert Layout(np.array([[True, False], [True, True]])).num_tiles == 3


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        (dict(collision_shape="sphere"), LayoutError, "'sphere'"),
        (dict(mass=-1.0), LayoutError, "mass.*-1"),
        (dict(size=(0.1, 0.1)), LayoutError, "size"),
        (dict(collision_radius=0.0), LayoutError, "collision_radius.*0"),
        (dict(collision_half_size=(0.1, -0.1)), LayoutError, "collision_half_size"),
        (dict(margin=-0.01), LayoutError, "margin.*-0.01"),
        (dict(wall_margin=float("nan")), LayoutError, "wall_margin.*nan"),
        (dict(hover_gap=-0.001), LayoutError, "hover_gap.*-0.001"),
    ],
)
def test_bad_mover_specs(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        MoverSpec(**kwargs)


# ---------------------------------------------------------------------------------------------- start poses
def test_movers_off_the_tiles():
    layout = Layout(np.array([[1, 1], [1, 0]]))  # L-shape: tile (1, 1) is a hole
    with pytest.raises(LayoutError, match=r"mover 1 .*\(0\.36, 0\.36\).*off the tiles"):
        Simulator(layout, start_xy=[[0.12, 0.12], [0.36, 0.36]], device="cpu")
    with pytest.raises(LayoutError, match=r"mover 0 .*off the tiles"):
        Simulator(layout, start_xy=[[-0.3, 0.12]], device="cpu")
    with pytest.raises(LayoutError, match=r"mover 0 .*off the tiles"):  # inside, but the circle crosses the edge
        Simulator(layout, start_xy=[[0.05, 0.12]], device="cpu")
    with pytest.raises(LayoutError, match=r"mover 0 .*off the tiles"):  # a box at 45 degrees crosses the edge
        Simulator(layout, start_xy=[[0.12, 0.12]], start_yaw=[np.pi / 4], device="cpu",
                  mover=MoverSpec(collision_shape="box", collision_half_size=(0.1, 0.1)))
    Simulator(layout, start_xy=[[0.12, 0.12]], device="cpu", mover=MoverSpec(collision_shape="box"))  # fits at yaw 0


def test_overlapping_starts():
    with pytest.raises(LayoutError, match=r"movers 0 and 1 .*overlap.*\(0\.12, 0\.12\).*\(0\.2, 0\.12\)"):
        Simulator(L3, start_xy=[[0.12, 0.12], [0.2, 0.12]], device="cpu")
    # per-world start poses: the overlap is in world 1 only
    xy = np.array([[[0.12, 0.12], [0.6, 0.6]], [[0.36, 0.36], [0.40, 0.40]]])
    with pytest.raises(LayoutError, match=r"movers 0 and 1 .*world 1.*overlap"):
        Simulator(L3, start_xy=xy, num_worlds=2, device="cpu")
    # margins count: 0.24 apart is fine with radius 0.11, not with a 0.02 margin each
    Simulator(L3, start_xy=[[0.12, 0.12], [0.36, 0.12]], device="cpu")
    with pytest.raises(LayoutError, match="overlap"):
        Simulator(L3, start_xy=[[0.12, 0.12], [0.36, 0.12]], device="cpu", mover=MoverSpec(margin=0.02))


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        (dict(start_xy=np.zeros((3, 3))), LayoutError, r"start_xy.*\(3, 3\)"),
        (dict(start_xy=np.zeros(4)), LayoutError, r"start_xy.*\(4,\)"),
        (dict(start_xy=[[0.12, 0.12]], start_yaw=[0.0, 0.0]), LayoutError, r"start_yaw.*\(2,\)"),
        (dict(start_xy=[[0.12, 0.12]], start_yaw=[np.inf]), LayoutError, "start_yaw"),
        (dict(start_xy=[[0.12, 0.12]], num_movers=2), LayoutError, "num_movers=2"),
        (dict(num_movers=10), LayoutError, r"num_movers=10.*9 tiles"),
        (dict(num_movers=0), ValueError, "num_movers must be >= 1, got 0"),
        (dict(), ValueError, "num_movers or start_xy"),
        (dict(num_movers=1, num_worlds=0), ValueError, "num_worlds must be >= 1, got 0"),
        (dict(num_movers=1, control="velocity"), ValueError, "'velocity'"),
        (dict(num_movers=1, dt=0.0), ValueError, "dt.*0.0"),
        (dict(num_movers=1, v_max=-2.0), ValueError, "v_max.*-2.0"),
        (dict(num_movers=1, a_max=float("inf")), ValueError, "a_max.*inf"),
        (dict(num_movers=1, stiffness_lin=(1, 1)), ValueError, "stiffness_lin"),
        (dict(num_movers=1, stiffness_rot=(0.1, -0.1, 1)), ValueError, "stiffness_rot"),
        (dict(num_movers=1, stiffness_rot=""), TypeError, "stiffness_rot must be 3 finite non-negative numbers, got ''"),
        (dict(num_movers=1, hold_mask="cuda:7"), TypeError, "hold_mask must be six 0/1 flags.*'cuda:7'"),
        (dict(start_xy=[["a", "b"]]), TypeError, r"start_xy must be numbers \(an array\), got \[\['a', 'b'\]\]"),
        (dict(num_movers=1, start_yaw="x"), TypeError, "start_yaw must be numbers"),
        (dict(start_pose="x"), TypeError, "start_pose must be numbers"),
        (dict(num_movers=2, collision_radii="x"), TypeError, "collision_radii must be numbers"),
        (dict(num_movers=2, collision_half_sizes=[[0.1, "y"], [0.1, 0.1]]), TypeError, "collision_half_sizes must be"),
        (dict(num_movers=1, stiffness_lin=("a", 1, 1)), TypeError, r"stiffness_lin must be 3 .*'a'"),
        (dict(num_movers=1, hold_mask=(0, 0, 1, 1, 1)), ValueError, "hold_mask"),
        (dict(num_movers=1, hold_mask=(0, 0, 2, 1, 1, 1)), ValueError, "hold_mask"),
        (dict(num_movers=2, collision_radii=[0.1]), ValueError, r"collision_radii.*2"),
        (dict(num_movers=2, collision_radii=[0.1, -0.1]), ValueError, "collision_radii"),
        (dict(num_movers=2, collision_half_sizes=np.ones((2, 3))), ValueError, r"collision_half_sizes.*\(2, 3\)"),
        (dict(num_movers=1, force_aux_dim=0), ValueError, "force_aux_dim.*0"),
    ],
)
def test_bad_simulator_arguments(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        Simulator(L3, device="cpu", **kwargs)


@pytest.mark.parametrize("device", ["tpu", "cuda:7"])
def test_unknown_device(device):
    with pytest.raises(ValueError, match=device):
        Simulator(L3, num_movers=1, device=device)


# ---------------------------------------------------------------------------------------------- commands
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_commands_are_rejected_without_side_effects(sim, bad):
    before = state_copy(sim)
    cmd = torch.zeros(2, 3, 2)
    cmd[1, 2, 0] = bad
    with pytest.raises(ValueError, match=rf"non-finite.*\[1, 2, 0\].*{bad}"):
        sim.set_command(cmd)
    assert_state_equal(before, state_copy(sim))
    with pytest.raises(ValueError, match="non-finite"):
        sim.step(10, cmd=cmd)  # the step does not run either
    assert_state_equal(before, state_copy(sim))
    with pytest.raises(ValueError, match="non-finite"):
        sim.set_command(cmd.numpy())  # numpy input gets the same check
    with pytest.raises(ValueError, match="yaw target.*non-finite"):
        sim.set_targets(yaw=torch.full((2, 3), bad))
    with pytest.raises(ValueError, match="z target.*non-finite"):
        sim.set_targets(z=torch.full((2, 3), bad))
    assert_state_equal(before, state_copy(sim))


def test_command_shape_dtype_device(sim):
    before = state_copy(sim)
    with pytest.raises(ValueError, match=r"shape \(2, 3, 2\), got \(2, 3\)"):
        sim.set_command(torch.zeros(2, 3))
    with pytest.raises(ValueError, match=r"got \(1, 3, 2\)"):
        sim.step(1, cmd=torch.zeros(1, 3, 2))
    with pytest.raises(TypeError, match="floating point.*torch.int64"):
        sim.set_command(torch.zeros(2, 3, 2, dtype=torch.int64))
    with pytest.raises(TypeError, match="floating point.*torch.bool"):
        sim.set_command(torch.zeros(2, 3, 2, dtype=torch.bool))
    with pytest.raises(ValueError, match="device meta.*cpu"):
        sim.set_command(torch.zeros(2, 3, 2, device="meta"))
    with pytest.raises(ValueError, match=r"yaw target must have shape \(2, 3\)"):
        sim.set_targets(yaw=torch.zeros(3))
    assert_state_equal(before, state_copy(sim))
    sim.set_command(torch.zeros(2, 3, 2, dtype=torch.float64))  # other float dtypes are converted
    sim.set_command(np.zeros((2, 3, 2)))  # and so are arrays on the host


def test_bad_step_counts(sim):
    for n in (0, -3):
        with pytest.raises(ValueError, match=f"num_cycles must be >= 1, got {n}"):
            sim.step(n)


# ---------------------------------------------------------------------------------------------- reset masks
def test_bad_reset_masks(sim):
    before = state_copy(sim)
    with pytest.raises(ValueError, match=r"shape \(2,\), got \(3,\)"):
        sim.reset(torch.ones(3, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"shape \(2,\), got \(2, 1\)"):
        sim.reset(torch.ones(2, 1, dtype=torch.bool))
    with pytest.raises(TypeError, match="bool or integer.*float32"):
        sim.reset(torch.ones(2, dtype=torch.float32))
    with pytest.raises(ValueError, match="meta"):
        sim.reset(torch.ones(2, dtype=torch.bool, device="meta"))
    assert_state_equal(before, state_copy(sim))
    sim.reset(np.array([False, False]))  # an all-false mask is valid and changes nothing
    assert_state_equal(before, state_copy(sim))


def test_float64_command_overflowing_float32_is_rejected(sim):
    """The state is float32: a finite float64 command of 1e40 would be stored as inf (and poison the state)."""
    before = state_copy(sim)
    cmd = torch.zeros(2, 3, 2, dtype=torch.float64)
    cmd[0, 1, 1] = 1e40
    with pytest.raises(ValueError, match=r"non-finite.*\[0, 1, 1\]"):
        sim.step(3, cmd=cmd)
    assert_state_equal(before, state_copy(sim))
    assert torch.isfinite(sim.pos).all()
