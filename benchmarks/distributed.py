"""Training throughput through torch.distributed: one process without torchrun beside torchrun with 1, 2, 4, 8 ranks.

World size 1 runs the same code path as a multi-GPU job (process group, gradient all-reduce, broadcast decisions);
its env-steps/s should equal the plain process's within noise. With several GPUs every rank steps ``--num-envs``
worlds on its own GPU, so the whole job's env-steps/s should grow with the rank count. Each run trains for
``--seconds`` (compilation excluded: the training clock starts after the first env step) with no periodic
evaluation; the figure is the mean of its log rows' steps/s after the first row (warm-up), all ranks together.

    python benchmarks/distributed.py --device cuda --json distributed.json        # 1 GPU and every larger count present
    python benchmarks/distributed.py --device cuda --procs 1,2,4,8 --seconds 60   # a machine with 8 GPUs
    python benchmarks/distributed.py --device cpu --smoke --procs 1,2 --seconds 8  # CPU smoke check (gloo)
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import header_line, machine_info, print_table, provenance, write_json  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
DEFAULT_RUNS = "b0_ppo_starts40,pushbox_sac"
# --smoke: one mover on 3 x 3 tiles and small networks, so every mode runs in seconds on a CPU
SMOKE = {
    "ppo": ["--env-id", "magwarp/TrajectoryPlanning-v0", "--env-kwargs",
            '{"layout": [[1, 1, 1], [1, 1, 1], [1, 1, 1]], "num_movers": 1}', "--num-envs", "64", "--num-steps", "8",
            "--hidden", "32,32"],
    "sac-her": ["--env-id", "magwarp/TrajectoryPlanning-v0", "--env-kwargs",
                '{"layout": [[1, 1, 1], [1, 1, 1], [1, 1, 1]], "num_movers": 1}', "--num-envs", "64",
                "--hidden", "32,32", "--batch-size", "256", "--updates-per-step", "4", "--learning-starts", "2",
                "--buffer-steps", "64"],
}
MODULES = {"ppo": "magwarp.training.ppo", "sac-her": "magwarp.training.sac_her"}


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda", help="cuda (ranks on cuda:0..N-1) or cpu (gloo)")
    p.add_argument("--procs", default=None,
                   help="rank counts, comma separated (default: 1, 2, 4, 8 up to the GPUs present; CPU: 1,2)")
    p.add_argument("--runs", default=DEFAULT_RUNS, help="paper runs (magwarp.training.paper), comma separated")
    p.add_argument("--smoke", action="store_true", help="tiny PPO and SAC+HER runs instead of the paper runs")
    p.add_argument("--seconds", type=float, default=30.0, help="training seconds of each run")
    p.add_argument("--args", default="", help="more options for every training run, quoted")
    p.add_argument("--json", default=None, help="write the rows and the machine info here")
    return p.parse_args(argv)


def _runs(args) -> list[tuple[str, str, list[str]]]:
    """(name, algo, training options) of every run to time."""
    if args.smoke:
        return [(f"smoke_{algo}", algo, opts) for algo, opts in SMOKE.items()]
    from magwarp.training.paper import PAPER_RUNS

    out = []
    for name in args.runs.split(","):
        run = PAPER_RUNS[name.strip()]
        out.append((name.strip(), run.algo, ["--env-id", run.env_id, "--env-kwargs", run.train_json(),
                                             *run.script_args]))
    return out


def _procs(args) -> list[int]:
    if args.procs:
        return [int(x) for x in args.procs.split(",")]
    if args.device.startswith("cuda"):
        import torch

        gpus = torch.cuda.device_count()
        if gpus == 0:
            raise SystemExit("no CUDA device visible: use --device cpu")
        return [n for n in (1, 2, 4, 8) if n <= gpus]
    return [1, 2]


def _sps(out: Path) -> tuple[float, int]:
    """Mean steps/s of the log rows after the first (all ranks together), and the env steps trained."""
    with open(out / "progress.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    summary = json.loads((out / "run.json").read_text())["summary"]
    later = [float(r["sps"]) for r in rows[1:]] or [summary["global_step"] / max(summary["wall_s"], 1e-9)]
    return sum(later) / len(later), int(summary["global_step"])


def time_run(algo: str, opts: list[str], device: str, procs: int | None, seconds: float, extra: list[str],
             work: Path) -> dict:
    """Train once: ``procs`` None is a plain process, else torchrun with ``procs`` ranks. Returns the row."""
    out = work / f"{algo}_{'plain' if procs is None else procs}"
    train = ["--device", device, "--minutes", str(seconds / 60), "--out", str(out), "--no-progress",
             "--eval-steps", "0", "--eval-every", "0", "--checkpoint-every", "1e9",
             "--log-every", str(max(seconds / 6, 0.5)), *opts, *extra]
    if procs is None:
        cmd = [sys.executable, "-m", MODULES[algo], *train]
    else:
        cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", str(procs),
               "-m", MODULES[algo], *train]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])]))
    start = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")
    sps, steps = _sps(out)
    return {"mode": "plain" if procs is None else "torchrun", "ranks": procs or 1, "env_steps_per_s": sps,
            "per_rank": sps / (procs or 1), "env_steps": steps, "process_s": time.perf_counter() - start}


def main(argv=None) -> int:
    args = parse_args(argv)
    import shlex

    info = machine_info(args.device)
    print(header_line(info))
    extra = shlex.split(args.args)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, algo, opts in _runs(args):
            plain = time_run(algo, opts, args.device, None, args.seconds, extra, Path(tmp) / name)
            rows.append({"run": name, "algo": algo, **plain, "vs_plain": 1.0})
            print(f"{name}: plain {plain['env_steps_per_s']:,.0f} env-steps/s", flush=True)
            for n in _procs(args):
                row = time_run(algo, opts, args.device, n, args.seconds, extra, Path(tmp) / name)
                rows.append({"run": name, "algo": algo, **row, "vs_plain": row["env_steps_per_s"] /
                             plain["env_steps_per_s"]})
                print(f"{name}: torchrun x{n} {row['env_steps_per_s']:,.0f} env-steps/s", flush=True)
    print()
    print_table(rows, ["run", "mode", "ranks", ("env_steps_per_s", "env-steps/s"), ("per_rank", "per rank"),
                       ("vs_plain", "x plain"), ("env_steps", "env steps")])
    if args.json:
        write_json(args.json, {"machine": provenance(info), "seconds": args.seconds, "rows": rows})
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
