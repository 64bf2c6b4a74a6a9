"""torch.distributed training and evaluation on the CPU: two gloo processes launched by torchrun.

Averaged gradients equal the single-process gradient of the union of the ranks' batches; after a few PPO and SAC
updates every rank holds bit-identical parameters (and a one-process run resumes the two-rank checkpoint); a 2-rank
``magwarp eval`` prints the table of a 1-rank eval of the same seeds; a rank that is killed, or that stops
answering, ends the job with an error naming it within the timeout.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parent.parent
WORKER = REPO / "tests" / "dist_worker.py"
TINY_ENV = "magwarp/TrajectoryPlanning-v0"
TINY_KWARGS = '{"layout": [[1, 1, 1], [1, 1, 1], [1, 1, 1]], "num_movers": 1}'
TORCHRUN = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2"]


def _env() -> dict[str, str]:
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    return env


def _run(cmd: list[str], timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=timeout, cwd=REPO)


def test_averaged_gradient_equals_the_gradient_of_the_union_of_batches_and_divergence_is_caught(tmp_path):
    proc = _run([*TORCHRUN, str(WORKER), "grad", str(tmp_path)])
    assert proc.returncode == 0, proc.stderr[-3000:]
    for rank in (0, 1):
        out = json.loads((tmp_path / f"grad_rank{rank}.json").read_text())
        assert out["world"] == 2 and out["max_grad"] > 1e-2  # a real gradient, not zeros
        assert out["max_diff"] <= 1e-6, out
        assert "ranks [1] hold other parameters than rank 0" in out["diverged"]


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_ranks_hold_identical_parameters_after_updates_and_resume_in_one_process(tmp_path, algo):
    common = ["--env-id", TINY_ENV, "--env-kwargs", TINY_KWARGS, "--device", "cpu", "--num-envs", "16",
              "--no-progress", "--eval-steps", "0", "--out", str(tmp_path / "run"), "--log-every", "1000"]
    if algo == "ppo":  # 3 iterations of 2 ranks x 16 envs x 8 steps, 4 minibatch updates each
        extra = ["--num-steps", "8", "--hidden", "16,16", "--total-steps", "768"]
    else:  # 6 env steps of 2 ranks x 16 envs; 4 learning steps of 4 updates
        extra = ["--hidden", "16,16", "--batch-size", "32", "--learning-starts", "2", "--buffer-steps", "16",
                 "--updates-per-step", "4", "--total-steps", "192"]
    proc = _run([*TORCHRUN, str(WORKER), algo, str(tmp_path), *common, *extra])
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    r0, r1 = (torch.load(tmp_path / f"rank{r}.pt", weights_only=False) for r in (0, 1))
    assert r0["summary"]["global_step"] == r1["summary"]["global_step"] == int(extra[-1])
    assert len(r0["tensors"]) == len(r1["tensors"]) > 4
    assert all(torch.equal(a, b) for a, b in zip(r0["tensors"], r1["tensors"])), "ranks diverged"
    assert any(not torch.equal(a, b) for a, b in zip(r0["tensors"], r0["initial"])), "no update happened"
    assert r0["summary"]["success_rate"] == r1["summary"]["success_rate"]  # counters summed over the ranks

    # the two-rank checkpoint continues in one process (any world size)
    from magwarp.training import ppo, sac_her

    module = ppo if algo == "ppo" else sac_her
    total = int(extra[-1]) + (256 if algo == "ppo" else 32)
    summary = module.train(module.parse_args(["--resume", str(tmp_path / "run"), "--total-steps", str(total),
                                              "--no-progress"]))
    assert summary["global_step"] == total


def _table(text: str) -> list[str]:
    """The table's rows, without the header (wall time) and the process-time row (a clock)."""
    return [line for line in text.splitlines() if line.startswith("|") and "Process Time" not in line]


def test_two_rank_eval_prints_the_one_rank_table(tmp_path, capsys):
    from magwarp.cli import main

    args = ["eval", "magwarp/TrajectoryPlanningB0-v0", "--policy", "pretrained:b0_ppo", "--device", "cpu",
            "--episodes", "3", "--repeats", "4", "--steps", "20"]
    proc = _run([sys.executable, "-m", "magwarp", *args, "--nproc-per-node", "2", "--json", str(tmp_path / "two.json")])
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert main([*args, "--max-worlds", "6", "--json", str(tmp_path / "one.json")]) == 0  # 2 repeats per batch
    one = capsys.readouterr().out
    assert proc.stdout.count("| Success Rate") == 1  # rank 0 alone prints
    assert _table(proc.stdout) == _table(one) and len(_table(one)) > 5
    a, b = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("one", "two"))
    rows = {r["key"]: r["values"] for r in a["rows"] if r["key"] != "process_time_ms"}
    assert rows == {r["key"]: r["values"] for r in b["rows"] if r["key"] != "process_time_ms"}
    assert len(rows["success_rate"]) == 4


def _children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry.name))
    return out


def _rank_pid(root: int, local_rank: int) -> int | None:
    """The process of ``local_rank`` among the descendants of ``root`` (its LOCAL_RANK environment variable)."""
    todo = [root]
    while todo:
        pid = todo.pop()
        try:
            environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        except OSError:
            environ = []
        if f"LOCAL_RANK={local_rank}".encode() in environ and pid != root:
            return pid
        todo += _children(pid)
    return None


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the rank's process through /proc")
def test_a_killed_rank_ends_the_job_with_an_error_naming_it(tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "magwarp", "train", TINY_ENV, "--device", "cpu", "--num-envs", "16",
           "--env-kwargs", TINY_KWARGS, "--minutes", "5", "--out", str(out), "--nproc-per-node", "2",
           "--args", "--num-steps 8 --hidden 16,16 --no-progress --log-every 0.2 --dist-timeout 20"]
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO)
    try:
        deadline = time.time() + 120
        while not (out / "progress.csv").is_file():  # rank 0 has logged: both ranks are training
            assert proc.poll() is None and time.time() < deadline, "training did not start"
            time.sleep(0.2)
        victim = _rank_pid(proc.pid, 1)
        assert victim is not None
        os.kill(victim, signal.SIGKILL)
        start = time.time()
        output, _ = proc.communicate(timeout=60)
        ended = time.time() - start
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1 and ended < 20, (proc.returncode, ended, output[-3000:])
    assert "local_rank: 1" in output and "SIGKILL" in output
    assert f"magwarp train --resume {out} --nproc-per-node 2" in output


def test_a_rank_that_stops_answering_fails_the_collective_after_its_timeout():
    start = time.time()
    proc = _run([*TORCHRUN, str(WORKER), "hang", "/nonexistent"], timeout=120)
    assert proc.returncode != 0 and time.time() - start < 60
    assert "Timed out" in proc.stderr and "rank      : 0" in proc.stderr, proc.stderr[-3000:]


def test_train_command_launches_torchrun_with_the_module_and_its_options(tmp_path, monkeypatch, capsys):
    """``magwarp train --nproc-per-node N`` is torchrun over the training module with the same options (standalone
    on one machine; a rendezvous from --torchrun-args); a failed job names the resume command."""
    from magwarp.cli import main
    from magwarp.training import distributed

    calls = []
    monkeypatch.setattr(distributed.subprocess, "call", lambda cmd, env: calls.append((cmd, env)) or 0)
    argv = ["train", TINY_ENV, "--algo", "sac-her", "--device", "cpu", "--num-envs", "8", "--minutes", "1",
            "--out", str(tmp_path), "--nproc-per-node", "3", "--args", "--hidden 16,16"]
    assert main(argv) == 0 and "done on 3 processes" in capsys.readouterr().out
    cmd, env = calls[0]
    assert cmd[:6] == [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "3"]
    assert cmd[6:8] == ["-m", "magwarp.training.sac_her"] and cmd[cmd.index("--num-envs") + 1] == "8"
    assert cmd[-2:] == ["--hidden", "16,16"] and env["PYTHONPATH"].split(os.pathsep)[0] == str(REPO)
    assert main([*argv, "--torchrun-args", "--nnodes 2 --node-rank 1 --rdzv-endpoint h:29400"]) == 0
    cmd = calls[1][0]
    assert "--standalone" not in cmd
    assert cmd[5:11] == ["--nnodes", "2", "--node-rank", "1", "--rdzv-endpoint", "h:29400"]
    monkeypatch.setattr(distributed.subprocess, "call", lambda cmd, env: 1)
    assert main(argv) == 1
    assert f"magwarp train --resume {tmp_path} --nproc-per-node 3" in capsys.readouterr().err
    assert main([*argv[:-4], "--nproc-per-node", "0"]) == 2
