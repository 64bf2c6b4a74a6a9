"""The levitation tasks (liftoff, track, move, payload, pendulum): gymnasium's check on every id, the PD baseline
through the commutation succeeds on small batches, what each task adds is physically there (a payload the PD must
carry, a swing that pushes the mover, a reference that moves, energy that grows as the move's deadline shrinks),
``magwarp eval``'s levitation rows, and bad options refused by name."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

from magnetics_helpers import coarse_model, magnetics_cache  # noqa: F401  (tests/ is on sys.path; a fixture)

import magwarp  # noqa: F401  (registers the ids)
from magwarp.envs.levitation import LevitationEnv
from magwarp.envs.levitation_tasks import MoveOptions, PayloadOptions, PendulumOptions, TrackOptions
from magwarp.policies.levitation import LevitationPD

MAG = coarse_model(yaw_steps=8)  # coarse in yaw too: the table builds in a few seconds

IDS = {"LevitationLiftoff-v0": 19, "LevitationTrack-v0": 33, "LevitationMove-v0": 20, "LevitationPayload-v0": 23,
       "LevitationPendulum-v0": 23}


def _env(task, n=4, **kw):
    return LevitationEnv(n, task=task, magnetics=MAG, device="cpu", seed=3, autoreset=False, **kw)


def _run(env, policy, steps, seed=1):
    obs, _ = env.reset(seed=seed)
    out = []
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        assert not terminated.any(), info["pos_error"]
        out.append((obs, reward, info))
    return out


@pytest.mark.parametrize("env_id", sorted(IDS))
def test_check_env_and_observation_layout(env_id):
    from gymnasium.utils.env_checker import check_env

    env = gym.make(f"magwarp/{env_id}", magnetics=MAG, device="cpu")
    check_env(env.unwrapped, skip_render_check=True)
    vec = gym.make_vec(f"magwarp/{env_id}", num_envs=2, magnetics=MAG, device="cpu")
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (2, IDS[env_id]) == (2, vec.single_observation_space.shape[0])
    slices = vec.obs_slices
    assert slices["pos_error"] == slice(16, 19) and max(s.stop for s in slices.values()) == IDS[env_id]
    assert sum(s.stop - s.start for s in slices.values()) == IDS[env_id]


@pytest.mark.parametrize("action", ["currents", "wrench"])
def test_liftoff_rises_from_its_support(action):
    env = _env("liftoff", action=action)
    obs, _ = env.reset(seed=1)
    gap = obs[:, 2] - env.bottom
    np.testing.assert_allclose(gap.numpy(), 0.002, atol=1e-7)
    assert torch.all(env.reference[:, 2] - env.bottom >= 0.003) and torch.all(obs[:, 6:12] == 0)
    steps = _run(env, LevitationPD(env), 150)
    pos_err, rot_err = env.errors()
    assert pos_err.max() < 5e-5 and rot_err.max() < 1e-3, (pos_err, rot_err)
    assert steps[-1][2]["is_success"].all()
    if action == "wrench":
        return
    # without current it rests on its support: no fall, no failure, no success
    zero = torch.zeros((4, env.actuator.slots))
    env.reset(seed=1)
    for _ in range(40):
        obs, reward, terminated, _, info = env.step(zero)
    assert not terminated.any() and not info["is_success"].any()
    np.testing.assert_allclose((obs[:, 2] - env.bottom).numpy(), 0.002, atol=1e-7)
    assert torch.all(obs[:, 8] == 0)  # vertical velocity
    # released instead of resting, it drops out of the fail gap's 1 mm within ~15 ms (sqrt(2 * 1 mm / g) = 14 ms)
    env = _env("liftoff", task_options={"support": False})
    env.reset(seed=1)
    for k in range(40):
        _, reward, terminated, _, _ = env.step(zero)
        if terminated.all():
            break
    assert terminated.all() and 10 <= k <= 20 and torch.all(reward == env.failure_reward)


def test_resting_support_matches_numpy(rng):
    """One cycle of free fall onto the support, against numpy: centres below it are put on it, downward velocities
    there dropped; the others fall freely."""
    from magwarp.layout import Layout
    from magwarp.magnetics.drive import AUX_DIM, magnetic_force
    from magwarp.sim import Simulator
    from magwarp.support import RestingSupport

    W, dt, g = 32, 2.5e-4, 9.81
    sim = Simulator(Layout.grid(2, 2), 1, W, dt=dt, hold_mask=(0,) * 6, force_model=magnetic_force,
                    force_aux_dim=AUX_DIM, stop_on_collision=False, device="cpu")
    support = RestingSupport(sim, 0.008)
    support.height[: W // 4] = float("-inf")  # no support there
    z = rng.uniform(0.0079, 0.0081, W).astype(np.float32)
    vz = rng.uniform(-0.5, 0.5, W).astype(np.float32)
    sim.pos[:, 0, 2], sim.vel[:, 0, 2] = torch.as_tensor(z), torch.as_tensor(vz)
    sim.step(1)
    v1 = vz.astype(np.float64) - g * dt
    z1 = z + v1 * dt
    height = support.height.numpy().astype(np.float64)
    below = z1 < height
    want_z = np.where(below, height, z1)
    want_v = np.where(below, np.maximum(v1, 0.0), v1)
    np.testing.assert_allclose(sim.pos[:, 0, 2].numpy(), want_z, atol=1e-8, err_msg=str(rng))
    np.testing.assert_allclose(sim.vel[:, 0, 2].numpy(), want_v, atol=1e-6, err_msg=str(rng))
    assert below.any() and (~below).any(), rng
    with pytest.raises(ValueError, match="height must be a number"):
        RestingSupport(sim, float("nan"))


def test_track_reference_moves_and_the_baseline_follows_it():
    env = _env("track", task_options={"range": 0.004, "frequency": (2.0, 4.0)})
    policy = LevitationPD(env)
    steps = _run(env, policy, 200)
    s = env.obs_slices
    ref = torch.stack([torch.cat([o[:, s["reference"]], o[:, s["reference_tilt"]]], 1) for o, _, _ in steps])
    vel = torch.stack([o[:, s["reference_vel"]] for o, _, _ in steps])
    assert (ref[:, :, :2].amax(0) - ref[:, :, :2].amin(0)).max() > 2e-3  # it moves millimetres in x/y
    # the reference's rates are its derivatives (central differences; order x, y, z, yaw, roll, pitch -> rates
    # x, y, z, roll, pitch, yaw)
    fd = (ref[2:] - ref[:-2]) / (2 * env.step_dt)
    fd = fd[..., [0, 1, 2, 4, 5, 3]]
    np.testing.assert_allclose(vel[1:-1].numpy(), fd.numpy(), atol=2e-3 * float(vel.abs().max()))
    errs = torch.stack([info["pos_error"] for _, _, info in steps])
    rots = torch.stack([info["rot_error"] for _, _, info in steps])
    assert errs[100:].max() < 5e-5 and rots[100:].max() < 1e-3, (errs[100:].max(), rots[100:].max())
    # without the reference's rates (a plain PD on the moving pose) the tracking lags
    plain = LevitationPD(env)
    plain.slices = {k: v for k, v in env.obs_slices.items() if k not in ("reference_vel", "reference_acc")}
    lag = torch.stack([info["pos_error"] for _, _, info in _run(env, plain, 200)])
    assert lag[100:].max() > 5 * errs[100:].max()


def test_move_arrives_by_its_deadline_on_the_least_acceleration_plan():
    time = 0.25
    env = _env("move", max_episode_steps=300, task_options=MoveOptions(distance=(0.02, 0.04), time=time))
    obs, _ = env.reset(seed=1)
    dist = torch.linalg.vector_norm(obs[:, 16:18], dim=1)
    assert torch.all(dist >= 0.02 - 1e-6) and torch.all(dist <= 0.04 + 1e-6)
    policy = LevitationPD(env)
    # the first step's plan: the cubic from rest that arrives at rest by the deadline starts at 6 d / T^2
    force = policy.wrench(obs)[:, :2]
    want = env.mover.mass * 6 * (env.setpoint[:, :2] - obs[:, :2]) / time ** 2
    torch.testing.assert_close(force, want, rtol=1e-4, atol=1e-4)
    e0, spent = env.energy.clone(), torch.zeros(4, dtype=torch.float64)
    for k in range(env.max_episode_steps):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        spent += info["copper_loss"].double() * env.step_dt
        assert not terminated.any()
        left = obs[:, env.obs_slices["time_left"]][:, 0]
        if k == 10:  # before the deadline the reward is the copper loss alone
            torch.testing.assert_close(reward, -env.loss_weight * info["copper_loss"])
            assert torch.all(left > 0) and info["pos_error"].min() > 5e-3
        if k + 1 == round(time / env.step_dt):  # at the deadline: arrived
            assert torch.all(left == 0) and info["pos_error"].max() < 1e-3, info["pos_error"]
    assert truncated.all() and info["is_success"].all()
    np.testing.assert_allclose((env.energy - e0).numpy(), spent.numpy(), rtol=1e-5)


def test_payload_is_carried_and_shifts_the_centre_of_mass():
    env = _env("payload", task_options=PayloadOptions(mass=(0.2, 0.3), offset=0.04))
    obs, _ = env.reset(seed=1)
    s = env.obs_slices
    mass = obs[:, s["payload_mass"]][:, 0]
    assert torch.all((mass >= 0.2) & (mass <= 0.3))
    body = env.sim.model.body.numpy()
    np.testing.assert_allclose(body["mass"][:, 0], env.mover.mass + mass.numpy(), rtol=1e-6)
    assert np.abs(body["com"][:, 0, :2]).max() > 1e-3  # off the centre
    _run(env, LevitationPD(env), 150)
    pos_err, rot_err = env.errors()
    assert pos_err.max() < 1e-5 and rot_err.max() < 1e-4, (pos_err, rot_err)
    # a PD that does not know the payload sags under it and tilts towards it
    blind = LevitationPD(env)
    blind.slices = {k: v for k, v in env.obs_slices.items() if not k.startswith("payload")}
    _run(env, blind, 150)
    pos_err, rot_err = env.errors()
    assert pos_err.min() > 1e-4 and rot_err.max() > 1e-3, (pos_err, rot_err)


def test_pendulum_swings_and_the_baseline_holds_the_mover():
    env = _env("pendulum", task_options=PendulumOptions(angle=(0.2, 0.3)))
    s = env.obs_slices
    steps = _run(env, LevitationPD(env), 300)
    angles = torch.stack([o[:, s["swing_angle"]] for o, _, _ in steps])
    swing = torch.linalg.vector_norm(angles, dim=-1)
    assert swing.amax(0).min() > 0.15  # still swinging (period ~0.57 s: the 0.3 s see a half swing)
    a, r = env.task_terms.swing.swing()
    torch.testing.assert_close(steps[-1][0][:, s["swing_angle"]], a[:, 0])
    torch.testing.assert_close(steps[-1][0][:, s["swing_rate"]], r[:, 0])
    errs = torch.stack([info["pos_error"] for _, _, info in steps])
    assert errs.max() < 1e-4 and steps[-1][2]["is_success"].all(), errs.max()
    dump = env.state_arrays([1, 3])  # a bug report carries the bob's state
    np.testing.assert_array_equal(dump["pendulum_rod"], env.task_terms.swing.rod[[1, 3]].numpy())
    # the rod pushes the mover about: a PD that does not cancel it is pushed off by much more
    blind = LevitationPD(env)
    blind.slices = {k: v for k, v in env.obs_slices.items() if not k.startswith("swing")}
    pushed = torch.stack([info["pos_error"] for _, _, info in _run(env, blind, 300)])
    assert pushed.max() > 10 * errs.max()


def test_eval_reports_success_tracking_error_and_energy():
    from magwarp.evaluate import evaluate, format_table

    res = evaluate("LevitationLiftoff", "scripted", 2, 2, device="cpu", progress=False,
                   env_kwargs={"magnetics": MAG, "max_episode_steps": 120})
    rows = {r.key: r for r in res.rows}
    assert res.family == "levitation" and rows["success_rate"].mean == 100.0
    assert 0 < rows["tracking_error_mm"].mean < 1.0 and rows["final_position_error_mm"].mean < 0.1
    # the energy per episode is what the env's coils spent in the same episodes (same seeds)
    env = LevitationEnv(4, task="liftoff", magnetics=MAG, device="cpu", seed=0, autoreset=False)
    policy = LevitationPD(env)
    e0 = env.energy.clone()
    obs, _ = env.reset(seed=0)  # the evaluation's first batch: both repeats, 2 episodes each
    for _ in range(120):
        obs, *_ = env.step(policy(obs))
    want = (env.energy - e0).reshape(2, 2).mean(1).numpy()
    np.testing.assert_allclose(rows["episode_energy_j"].values, want, rtol=1e-4)
    assert rows["success_energy_j"].values == rows["episode_energy_j"].values
    assert "Copper Energy (J per success)" in format_table(res)


def test_bad_options_are_refused():
    def make(**kw):
        return LevitationEnv(1, magnetics=MAG, device="cpu", **kw)

    with pytest.raises(ValueError, match="'lift'"):
        make(task="lift")
    with pytest.raises(ValueError, match="takes no task_options"):
        make(task="hover", task_options={"time": 1.0})
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['speed'\]"):
        make(task="move", task_options={"speed": 1.0})
    with pytest.raises(TypeError, match="MoveOptions"):
        make(task="move", task_options=TrackOptions())
    with pytest.raises(ValueError, match=r"frequency .* got \(1.0, 0.5\)"):
        TrackOptions(frequency=(1.0, 0.5))
    with pytest.raises(ValueError, match="time .* got -1"):
        MoveOptions(time=-1)
    with pytest.raises(ValueError, match="does not fit the layout"):
        make(task="move", task_options={"distance": (0.1, 0.4)})
    with pytest.raises(ValueError, match=r"time 0.6 s must end before the episode"):
        make(task="move", task_options={"time": 0.6})
    with pytest.raises(ValueError, match="mass must be at most 5 kg"):
        PayloadOptions(mass=(0.1, 10.0))
    with pytest.raises(ValueError, match="angle must stay at most pi / 2"):
        PendulumOptions(angle=(0.1, 2.0))
    with pytest.raises(ValueError, match="pivot must be three"):
        PendulumOptions(pivot=(0.0, math.nan, 0.1))
    with pytest.raises(ValueError, match="start_gap 0.0015 must lie above"):
        make(task="liftoff", task_options={"start_gap": 0.0015})
    with pytest.raises(ValueError, match="start_gap must be a finite number"):
        make(task="liftoff", task_options={"start_gap": "low"})
    with pytest.raises(ValueError, match="support must be True or False, got 'yes'"):
        make(task="liftoff", task_options={"support": "yes"})
    with pytest.raises(ValueError, match="success_tol"):
        make(success_tol=(0.001, -1.0))
    env = make(task="hover")
    with pytest.raises(ValueError, match="max_acc"):
        LevitationPD(env, max_acc=(5.0, float("inf")))
