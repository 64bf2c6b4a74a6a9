"""Copper energy in ``magwarp eval``: rows for envs that run the magnetic model, none for the ideal model."""

from __future__ import annotations

import pytest

from magnetics_helpers import coarse_model, magnetics_cache  # noqa: E402, F401  (tests/ is on sys.path; a fixture)

from magwarp.evaluate import evaluate, format_table

MAG = coarse_model(gap=(0.003, 0.005), z_step=0.002, yaw_steps=8)


def test_trajectory_eval_reports_copper_energy():
    steps = 25
    res = evaluate("TrajectoryPlanningB0", "scripted", 2, 1, device="cpu", steps=steps, progress=False,
                   env_kwargs={"force_model": MAG})
    rows = {r.key: r for r in res.rows}
    power, joules = rows["copper_power_w"], rows["copper_energy_j_per_goal"]
    assert len(power.values) == 1 and 10.0 < power.mean < 1000.0, power.values  # hovering and moving: tens of W
    # J per goal = W per mover x 3 movers x 2 worlds x simulated seconds / the repeat's goals (the row's n)
    assert joules.n >= 1
    want = power.mean * 3 * 2 * steps * 40 * 1e-3 / joules.n
    assert joules.mean == pytest.approx(want, rel=1e-5)
    assert "Copper Energy (J per goal)" in format_table(res)


def test_ideal_model_reports_no_energy():
    res = evaluate("TrajectoryPlanningB0", "scripted", 1, 1, device="cpu", steps=2, progress=False)
    assert not any(r.key.startswith("copper") for r in res.rows)
