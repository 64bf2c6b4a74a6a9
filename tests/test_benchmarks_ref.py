"""Fast checks of the benchmark plumbing (benchmarks/common.py) and of the MagBotSim reference harness
(benchmarks/magbotsim_ref.py) at tiny sizes. No wall-clock assertions: only keys, signs and equivalences."""

import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import common  # noqa: E402

# ------------------------------------------------------------------ common.py


def test_format_table_aligns_columns():
    rows = [{"engine": "magwarp", "movers": 1000, "ms": 0.012345},
            {"engine": "magbotsim", "movers": 50, "ms": 3.5, "extra": 1}]
    text = common.format_table(rows, ["engine", "movers", ("ms", "ms/step"), "extra"])
    lines = text.splitlines()
    assert lines[0].split() == ["engine", "movers", "ms/step", "extra"]
    assert set(lines[1].replace(" ", "")) == {"-"}
    assert len({len(line) for line in lines[:2]}) == 1  # header and rule have the same width
    # numbers are right-aligned: the movers column ends at the same position in every data row
    ends = [line.index("1000") + 4 for line in lines[2:3]] + [line.index(" 50") + 3 for line in lines[3:4]]
    assert ends[0] == ends[1]
    assert "0.01235" in lines[2] and "3.5" in lines[3]
    assert lines[2].rstrip().endswith("-")  # missing value shown as '-'


def test_print_table_prints_and_returns(capsys):
    text = common.print_table([{"a": 1.0, "b": "x"}], ["a", "b"])
    assert capsys.readouterr().out.strip() == text.strip()


def test_format_value_edge_cases():
    assert common.format_value(None) == "-"
    assert common.format_value(True) == "True"
    assert common.format_value(np.float32(2.5)) == "2.5"
    assert common.format_value(1.23e-5) == "1.230e-05"
    assert common.format_value(123456.7) == "123457"
    assert common.format_value(7) == "7"


def test_json_round_trip(tmp_path):
    rows = [{"engine": "magbotsim", "movers": np.int64(8), "ms_per_step": np.float64(1.5), "arr": np.arange(3)}]
    path = common.write_json(tmp_path / "sub" / "rows.json", rows)
    back = common.read_json(path)
    assert back == [{"engine": "magbotsim", "movers": 8, "ms_per_step": 1.5, "arr": [0, 1, 2]}]
    assert json.loads(path.read_text()) == back


def test_time_call_counts_and_sync():
    calls = {"fn": 0, "sync": 0}

    def fn():
        calls["fn"] += 1
        time.sleep(0.001)

    def sync():
        calls["sync"] += 1

    mean, std, median = common.time_call(fn, repeats=5, warmup=2, sync=sync)
    assert calls["fn"] == 7
    assert calls["sync"] == 6  # once before the clock starts, then once per timed call
    assert mean >= 0.9 and median >= 0.9 and std >= 0  # each call sleeps 1 ms
    with pytest.raises(ValueError):
        common.time_call(fn, repeats=0)


def test_time_samples_returns_wall_and_cpu():
    wall, cpu = common.time_samples(lambda: sum(range(1000)), repeats=4)
    assert len(wall) == len(cpu) == 4 and all(w > 0 for w in wall) and all(c >= 0 for c in cpu)


def test_machine_info_and_markdown_header():
    info = common.machine_info("cpu")
    for key in ("device", "device_name", "date_utc", "versions", "argv", "command"):
        assert key in info
    assert info["versions"]["python"]
    assert set(common.VERSIONED_PACKAGES) <= set(info["versions"])
    assert info["date_utc"].endswith("UTC")
    md = common.markdown_header(info)
    for word in ("Device", "Date", "Versions", "Command", info["device_name"]):
        assert word in md
    assert common.command_line(["benchmarks/scaling.py", "--json", "a b.json"]) == \
        "python benchmarks/scaling.py --json 'a b.json'"


# ------------------------------------------------------------------ magbotsim_ref.py

SCALING_KEYS = {"engine", "variant", "device", "movers", "tiles", "shape", "ms_per_step", "mean_ms", "std_ms",
                "median_ms", "cpu_mean_ms", "construct_s", "collision_steps"}


@pytest.fixture(scope="module")
def ref():
    pytest.importorskip("magbotsim")
    import magbotsim_ref

    assert magbotsim_ref.magbotsim_available()
    return magbotsim_ref


@pytest.mark.parametrize("shape", ["circle", "box"])
@pytest.mark.parametrize("controllers", [False, True])
def test_scaling_step_small(ref, shape, controllers):
    row = ref.scaling_step_ms(8, (4, 4), shape, steps=3, controllers=controllers, warmup=1)
    assert SCALING_KEYS <= set(row)
    assert row["engine"] == ("magbotsim-controllers" if controllers else "magbotsim") and row["movers"] == 8 and row["tiles"] == "4x4"
    assert row["shape"] == shape and row["variant"] == ("controllers" if controllers else "vectorised")
    for key in ("ms_per_step", "mean_ms", "median_ms", "construct_s"):
        assert math.isfinite(row[key]) and row[key] > 0, (key, row[key])
    assert row["std_ms"] >= 0
    assert row["collision_steps"] == 0  # movers sit at tile centres and barely move


def test_scaling_env_is_the_paper_configuration(ref):
    env, ctrls = ref.build_scaling_env(8, "4x4", "box")
    centres = (2 * np.arange(4) + 1) * 0.12
    qpos = env.get_mover_qpos(env.mover_names)
    assert np.allclose(np.sort(np.unique(np.round(qpos[:, 0], 6))), centres[:2])  # 8 movers fill 2 columns
    assert np.allclose(np.unique(np.round(qpos[:, 1], 6)), centres)
    assert env.model.nu == 6 * 8 and len(ctrls) == 8
    assert all(len(c.actuator_ids) == 6 for c in ctrls)


def test_fast_name_extraction_matches_magbotsim(ref):
    import mujoco
    from magbotsim.utils import mujoco_utils

    env, _ = ref.build_scaling_env(6, 3, "circle", fast_construction=False)
    for obj in ("mjOBJ_BODY", "mjOBJ_JOINT", "mjOBJ_GEOM", "mjOBJ_SITE", "mjOBJ_ACTUATOR", "mjOBJ_SENSOR"):
        t = getattr(mujoco.mjtObj, obj)
        assert ref._extract_mj_names_linear(env.model, t) == mujoco_utils.extract_mj_names(env.model, t), obj
    original = mujoco_utils.extract_mj_names
    with ref.fast_name_extraction():
        assert mujoco_utils.extract_mj_names is ref._extract_mj_names_linear
    assert mujoco_utils.extract_mj_names is original
    fast_env, _ = ref.build_scaling_env(6, 3, "circle", fast_construction=True)
    assert fast_env.mover_names == env.mover_names and fast_env.mover_joint_names == env.mover_joint_names


def test_bad_scaling_arguments(ref):
    with pytest.raises(ValueError, match="shape"):
        ref.build_scaling_env(2, 2, "triangle")
    with pytest.raises(ValueError, match="do not fit"):
        ref.build_scaling_env(5, 2, "circle")


def test_env_steps_per_s_b0(ref):
    row = ref.env_steps_per_s("LongHorizonGlobalTrajectoryPlanningEnvB0-v0", steps=3, warmup=0)
    assert row["steps"] == 3 and row["steps_per_s"] > 0 and row["step_ms_mean"] > 0
    assert row["resets"] == row["terminated"] + row["truncated"] >= 0
    assert row["resets_timed"] is True
    assert 0 < row["cycles_per_step"] <= 40  # 40 cycles per env step unless a collision cuts it short


def test_rl_env_kwargs_fill_required_args(ref):
    assert ref.rl_env_kwargs("LongHorizonGlobalTrajectoryPlanningEnvB0-v0") == {"render_mode": None,
                                                                                  "show_2D_plot": False}
    assert ref.rl_env_kwargs("StateBasedPushBoxEnv-v0") == {"render_mode": None}


# ------------------------------------------------------------------ collisions_by_age.py


def test_collisions_by_age_matches_a_per_world_count():
    """The binned counts against a plain per-world replay of the same seeded run (the kept B0 policy, 32 worlds)."""
    import torch

    import collisions_by_age as cba
    from magwarp.training import make_env, pretrained_path
    from magwarp.training.policy import policy_metadata

    policy_path = pretrained_path("b0_ppo")
    worlds, steps, seed = 32, 40, 3
    rows = cba.count_by_age(policy_path, "cpu", worlds, steps, seed)
    assert [r["age_bin"] for r in rows] == ["0-2", "3-9", "10-29", "30-99", "100+", "all"]

    env, _ = make_env("magwarp/TrajectoryPlanningB0-v0", worlds, "cpu", seed,
                      json.loads(policy_metadata(policy_path)["eval_env_kwargs"]))
    policy = torch.jit.load(policy_path).eval()
    expect = {k: [0] * 5 for k in ("steps", "collisions", "timeouts", "goals")}
    ages = [0] * worlds
    obs, _ = env.reset(seed=seed)
    with torch.no_grad():
        for _ in range(steps):
            obs, _, term, trunc, info = env.step(policy(obs))
            for w in range(worlds):
                b = sum(ages[w] >= edge for edge in cba.BINS) - 1
                expect["steps"][b] += 1
                expect["collisions"][b] += int(term[w])
                expect["timeouts"][b] += int(trunc[w] and not term[w])
                expect["goals"][b] += int(info["goals_reached"][w].sum())
                ages[w] = 0 if (term[w] or trunc[w]) else ages[w] + 1
    for key, per_bin in expect.items():
        assert [r[key] for r in rows[:-1]] == per_bin, key
        assert rows[-1][key] == sum(per_bin), key
    assert sum(expect["steps"]) == worlds * steps and expect["steps"][0] >= worlds and expect["steps"][3] > 0
    assert sum(expect["goals"]) > 0
