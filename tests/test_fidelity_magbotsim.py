"""x/y motion against MagBotSim 1.3, per 1 ms cycle, in acceleration and jerk mode.

The same start poses and the same random action sequences (held 40 cycles each, the jerk ones reaching the speed
cap) run in MagBotSim's ``LongHorizonGlobalTrajectoryPlanningEnv`` (B0, the cycle loop of its ``env.step``, its
MuJoCo state read every cycle), in magwarp (``Simulator.step(1)`` per cycle) and in a float64 numpy replay of the law
(:func:`magwarp.reference.planar_cycle`). The float64 replay equals MagBotSim to ~1e-12 m, so the law is the same;
magwarp stays within float32 rounding of it: 1e-6 m over the first 2 s and 1e-5 m over 4 s.

The launch shapes (register-resident, fused per world, per cycle) run the same law: they are checked against the
float64 replay at every step end.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp import reference as ref
from magwarp.kernels import step as kstep
from magwarp.kernels.impedance import default_force
from magwarp.layout import benchmark_layout
from magwarp.sim import Simulator

HOLD = 40  # cycles per action, as an RL step
LIMITS = dict(dt=0.001, v_max=2.0, a_max=10.0, j_max=100.0)


def random_actions(rng, num_actions: int, num_movers: int, jerk: bool) -> np.ndarray:
    """Float32-representable actions (magwarp's commands are float32): jerks within +-20 m/s^3 per component, or
    accelerations within MagBotSim's action box, +-a_max per component (norms up to 1.41 a_max are norm-clipped)."""
    lim = 20.0 if jerk else LIMITS["a_max"]
    return rng.uniform(-lim, lim, (num_actions, num_movers, 2)).astype(np.float32).astype(np.float64)


def float32_rounding(exact: np.ndarray) -> float:
    """Float32 rounding of the start poses plus that of the outputs: one float32 ulp of the largest coordinate."""
    return float(2 * np.spacing(np.float32(np.abs(exact).max())))


def float64_replay(start: np.ndarray, actions: np.ndarray, jerk: bool) -> np.ndarray:
    """Positions ``(cycles, M, 2)`` of the exact law in float64."""
    p, v, a = start.copy(), np.zeros_like(start), np.zeros_like(start)
    out = []
    for k in range(len(actions) * HOLD):
        a, v, dp = ref.planar_cycle(v, a, actions[k // HOLD], jerk_mode=jerk, **LIMITS)
        p = p + dp
        out.append(p)
    return np.array(out)


def magbotsim_replay(jerk: bool, seed: int, num_actions: int, rng):
    """Start poses, actions, per-cycle positions and accelerations (qacc) of MagBotSim's B0 env."""
    pytest.importorskip("magbotsim")
    import mujoco
    from magbotsim.rl_envs.trajectory_planning.long_horizon_global_trajectory_planning_env import (
        LongHorizonGlobalTrajectoryPlanningEnv,
    )

    layout, num_movers = benchmark_layout("B0")
    env = LongHorizonGlobalTrajectoryPlanningEnv(layout_tiles=layout.tiles, num_movers=num_movers, show_2D_plot=False,
                                                 render_mode=None, std_noise=0.0, learn_jerk=jerk,
                                                 timeout_steps=None)
    env.reset(seed=seed)
    start = env.get_mover_qpos(env.mover_names)[:, :2].copy()
    actions = random_actions(rng, num_actions, num_movers, jerk)
    pos, acc = [], []
    for k in range(num_actions * HOLD):
        # env.step's cycle loop (its per-cycle collision checks, which change no state, left out for speed)
        if k % HOLD == 0:
            action = env._step_callback(actions[k // HOLD].reshape(-1))
        env._before_mujoco_step_callback(action)
        mujoco.mj_step(env.model, env.data, nstep=1)
        pos.append(env.get_mover_qpos(env.mover_names)[:, :2].copy())
        acc.append(env.get_mover_qacc(env.mover_names)[:, :2].copy())
    env.close()
    return layout, start, actions, np.array(pos), np.array(acc)


@pytest.mark.parametrize("control", ["acceleration", "jerk"])
def test_xy_motion_matches_magbotsim_per_cycle(control, rng):
    jerk = control == "jerk"
    num_actions = 100  # 4 s
    layout, start, actions, mbs_pos, mbs_acc = magbotsim_replay(jerk, int(rng.integers(1 << 30)), num_actions, rng)
    m = start.shape[0]
    exact = float64_replay(start, actions, jerk)
    # The law: a float64 replay equals MagBotSim (its MuJoCo state is float64) to round-off.
    np.testing.assert_allclose(exact, mbs_pos, atol=1e-9, err_msg=f"{rng}: float64 law vs MagBotSim")

    sim = Simulator(layout, m, start_xy=start, control=control, device="cpu", stop_on_collision=False)
    pos, acc = [], []
    for k in range(num_actions * HOLD):
        if k % HOLD == 0:
            sim.set_command(torch.as_tensor(actions[k // HOLD][None], dtype=torch.float32))
        sim.step(1)
        pos.append(sim.pos[0, :, :2].numpy().astype(np.float64))
        acc.append(sim.acc[0].numpy().astype(np.float64))
    pos, acc = np.array(pos), np.array(acc)
    err = np.abs(pos - mbs_pos).max(axis=(1, 2))
    half = len(err) // 2
    assert err[:half].max() <= 1e-6, f"{rng}: {err[:half].max():.3g} m from MagBotSim within 2 s"
    assert err.max() <= 1e-5, f"{rng}: {err.max():.3g} m from MagBotSim within 4 s"
    # What is left is float32 rounding: the outputs are the float64 law's rounded (start poses rounded to float32).
    np.testing.assert_allclose(pos, exact, atol=float32_rounding(exact), rtol=0,
                               err_msg=f"{rng}: magwarp vs the float64 law")
    # The acceleration (what observations show in jerk mode) is MagBotSim's qacc, rounded.
    np.testing.assert_allclose(acc, mbs_acc, atol=1e-5, rtol=1e-6, err_msg=f"{rng}: acceleration vs qacc")
    if jerk:  # the sequence reaches the speed cap, where a float32 law would lose the carried acceleration
        assert np.linalg.norm(np.diff(exact, axis=0) / LIMITS["dt"], axis=-1).max() > 0.999 * LIMITS["v_max"], str(rng)


@pytest.mark.parametrize("shape", ["register", "fused", "per_cycle"])
def test_every_launch_shape_runs_the_float64_law(shape, rng):
    """Jerk mode, 4 s, RL steps of 40 cycles: every launch shape stays within float32 rounding of the exact law."""
    layout, m = benchmark_layout("B0")
    start = np.array(layout.tile_centers()[:m], dtype=np.float64)
    actions = random_actions(rng, 100, m, jerk=True)
    sim = Simulator(layout, m, start_xy=start, control="jerk", device="cpu", stop_on_collision=False,
                    fused_max_movers=0 if shape == "per_cycle" else 16)
    if shape == "fused":  # the one-thread-per-world kernel that reads the state from memory (worlds of 9-16 movers)
        sim._fused_kernel = kstep.make_advance_kernel(default_force)[1]
    exact = float64_replay(start, actions, jerk=True)[HOLD - 1::HOLD]
    got = []
    for a in actions:
        sim.step(HOLD, torch.as_tensor(a[None], dtype=torch.float32))
        got.append(sim.pos[0, :, :2].numpy().astype(np.float64))
    np.testing.assert_allclose(np.array(got), exact, atol=float32_rounding(exact), rtol=0,
                               err_msg=f"{rng}: {shape}")


def test_writes_into_the_float32_state_restart_the_float64_state():
    """A position, velocity or acceleration written from outside is what the next cycle starts from."""
    sim = Simulator(benchmark_layout("B0")[0], 3, control="jerk", device="cpu", stop_on_collision=False)
    sim.step(40, torch.full((1, 3, 2), 50.0))
    sim.pos[0, 1, :2] = torch.tensor([0.3, 0.4])
    sim.vel[0, 1, :2] = torch.tensor([0.5, -0.25])
    sim.acc[0, 1] = torch.tensor([1.0, 2.0])
    sim.step(1, torch.zeros(1, 3, 2))
    want_a, want_v, dp = ref.planar_cycle(np.array([0.5, -0.25]), np.array([1.0, 2.0]), np.zeros(2), jerk_mode=True,
                                          **LIMITS)
    np.testing.assert_allclose(sim.acc[0, 1].numpy(), want_a, atol=1e-6)
    np.testing.assert_allclose(sim.vel[0, 1, :2].numpy(), want_v, atol=1e-7)
    np.testing.assert_allclose(sim.pos[0, 1, :2].numpy(), np.array([0.3, 0.4]) + dp, atol=1e-7)
