"""``magwarp eval`` on tiny inputs: the paper's table for a trajectory and a push env, every policy kind, JSON output,
and one-line errors for bad arguments."""

from __future__ import annotations

import json
import math

import pytest
import torch

from magwarp import cli
from magwarp.evaluate import evaluate, format_table


def run_cli(capsys, *argv):
    rc = cli.main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def _table_values(out: str) -> dict[str, str]:
    rows = {}
    for line in out.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0] not in ("Metric", "") and not cells[0].startswith("-"):
            rows[cells[0]] = cells[2]
    return rows


def test_eval_trajectory_env_prints_the_table_and_writes_json(capsys, tmp_path):
    path = tmp_path / "b0.json"
    rc, out, err = run_cli(capsys, "eval", "TrajectoryPlanningB0", "--episodes", "2", "--repeats", "2", "--steps", "6",
                           "--device", "cpu", "--json", str(path))
    assert rc == 0, err
    rows = _table_values(out)
    for label in ("Success Rate (%)", "Makespan (ms)", "Throughput (goals/s)", "Collisions (per 1000 goals)",
                  "Smoothness (per 1000 ms)", "Process Time (ms per goal, batched)"):
        assert label in rows, out
    data = json.loads(path.read_text())
    assert data["env_id"] == "magwarp/TrajectoryPlanningB0-v0" and data["repeats"] == 2 and data["family"] == "trajectory"
    smooth = next(r for r in data["rows"] if r["key"] == "smoothness")
    assert len(smooth["values"]) == 2 and all(v > 0 for v in smooth["values"])
    assert math.isclose(smooth["mean"], sum(smooth["values"]) / 2, rel_tol=1e-9)


def test_eval_push_env_with_scripted_policy(capsys):
    rc, out, err = run_cli(capsys, "eval", "magwarp/PushBox-v0", "--episodes", "3", "--repeats", "2", "--steps", "4",
                           "--device", "cpu")
    assert rc == 0, err
    rows = _table_values(out)
    assert rows["Mover-Mover Collisions"] == "---"  # one mover, as in the paper's table
    for label in ("Success Rate (%)", "Throughput (goals/s)", "Overshoot Corrections", "Distance Corrections",
                  "Collisions", "Mover-Obstacle Collisions"):
        assert label in rows, out
    assert "2 repeats x 3 episodes" in out


def test_env_options_from_the_command_line_or_the_policy_file(capsys, tmp_path):
    """--env-kwargs reaches the env; without it a trained policy file's eval_env_kwargs do (and are printed)."""
    from magwarp.training.policy import save_policy

    path = tmp_path / "b0.json"
    common = ["--episodes", "2", "--repeats", "1", "--device", "cpu", "--json", str(path)]
    rc, out, err = run_cli(capsys, "eval", "TrajectoryPlanningB0", "--env-kwargs", '{"num_cycles": 100}', *common)
    assert rc == 0, err
    assert json.loads(path.read_text())["steps_per_world"] == 100  # the default 10 s at 100 cycles per step

    # a policy file that says it is evaluated at 200 cycles per step (B0: 3 movers, observation 6 + goals 6 + 6)
    from magwarp.training.common import RunningMeanStd

    policy = tmp_path / "policy.pt"
    save_policy(str(policy), torch.nn.Linear(18, 6), RunningMeanStd(18, "cpu"), torch.full((6,), 10.0), squash="tanh",
                env_id="magwarp/TrajectoryPlanningB0-v0", metadata={"eval_env_kwargs": '{"num_cycles": 200}'})
    rc, out, err = run_cli(capsys, "eval", "TrajectoryPlanningB0", "--policy", str(policy), *common)
    assert rc == 0, err
    assert 'env options from' in out and '{"num_cycles": 200}' in out
    assert json.loads(path.read_text())["steps_per_world"] == 50
    rc, out, err = run_cli(capsys, "eval", "TrajectoryPlanningB0", "--policy", str(policy), "--env-kwargs", "{}", *common)
    assert rc == 0 and "env options from" not in out
    assert json.loads(path.read_text())["steps_per_world"] == 250
    # a run given only training options (--env-kwargs) is evaluated with them
    save_policy(str(policy), torch.nn.Linear(18, 6), RunningMeanStd(18, "cpu"), torch.full((6,), 10.0), squash="tanh",
                env_id="magwarp/TrajectoryPlanningB0-v0",
                metadata={"env_kwargs": '{"num_cycles": 125}', "eval_env_kwargs": None})
    rc, out, err = run_cli(capsys, "eval", "TrajectoryPlanningB0", "--policy", str(policy), *common)
    assert rc == 0 and '{"num_cycles": 125}' in out
    assert json.loads(path.read_text())["steps_per_world"] == 80


def test_eval_module_file_and_callable_policies(tmp_path):
    lin = torch.nn.Linear(8, 2)  # PushBox: achieved 2 + desired 2 + observation 4 -> 2 accelerations
    torch.nn.init.zeros_(lin.weight)
    torch.nn.init.zeros_(lin.bias)
    scripted, saved = tmp_path / "zero.ts", tmp_path / "zero.pt"
    torch.jit.script(lin).save(str(scripted))
    torch.save(lin, saved)
    # a whole pickled module runs code when unpickled: it loads only when trusted (tests/test_security.py)
    results = {p: evaluate("PushBox", str(p), 2, 1, device="cpu", steps=2, progress=False, trusted=p == saved)
               for p in (scripted, saved, "magwarp.policies.push:PushHeuristic")}
    for res in results.values():
        table = format_table(res)
        assert "Success Rate (%)" in table and res.rows[0].n == 2
    # a zero policy never moves the mover: no collisions, no smoothness effort beyond zero
    zero = results[scripted]
    assert next(r for r in zero.rows if r.key == "collisions").mean == 0


def test_repeats_split_over_batches_keep_one_value_per_repeat():
    res = evaluate("TrajectoryPlanningB0", "scripted", 2, 3, device="cpu", steps=4, max_worlds=4, progress=False)
    for row in res.rows[:-1]:  # the last row, process time, has one value per batch of repeats
        assert len(row.values) in (0, 3), row  # 0: mover-mover rows of one-mover envs (shown as ---)
    assert res.rows[-1].key == "process_time_ms" and len(res.rows[-1].values) == 2
    success = res.rows[0]
    assert len(success.values) == 3 and all(0 <= v <= 100 for v in success.values if math.isfinite(v))


@pytest.mark.parametrize("argv, message", [
    (["eval", "NoSuchEnv"], "unknown env 'NoSuchEnv'"),
    (["eval", "PushBox", "--episodes", "0"], "--episodes must be a positive integer"),
    (["eval", "PushBox", "--repeats", "x"], "invalid int value"),
    (["eval", "PushBox", "--policy", "nonsense"], "is not 'scripted', an existing file, or module:callable"),
    (["eval", "PushBox", "--policy", "no_such_module_xyz:f", "--episodes", "1", "--repeats", "1", "--device", "cpu"],
     "cannot import policy module"),
    (["eval", "PushBox", "--device", "tpu"], "device 'tpu' is not available"),
    (["eval", "PushBox", "--json", "/no/such/dir/out.json"], "does not exist"),
    (["eval", "PushBox", "--max-worlds", "0"], "--max-worlds must be >= 1"),
    (["eval", "PushBox", "--env-kwargs", "{bad"], "--env-kwargs must be a JSON object"),
    (["eval", "PushBox", "--env-kwargs", '{"no_such_option": 1}', "--episodes", "1", "--repeats", "1", "--device",
      "cpu"], "env options {'no_such_option': 1} do not fit magwarp/PushBox-v0"),
])
def test_bad_arguments_are_one_clear_line(capsys, argv, message):
    rc, _, err = run_cli(capsys, *argv)
    assert rc == 2 and err.count("\n") == 1 and message in err, err
