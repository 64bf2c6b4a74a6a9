"""The paper's training runs (Tables 3-5) side by side: one process each, spread over the visible GPUs.

    python -m magwarp.training.suite --minutes 8 --work runs --out $OUT            # first session
    python -m magwarp.training.suite --minutes 6 --work runs --out $OUT --resume   # continue the same runs

Each run (:data:`magwarp.training.paper.PAPER_RUNS`: env id, algorithm, and the env options the paper trained and
evaluated with) is ``python -m magwarp.training.ppo`` or ``python -m magwarp.training.sac_her`` writing
``WORK/<name>/`` (policy.pt, checkpoint.pt, progress.csv, curve.png, run.json) and ``WORK/<name>.log``. With
``--out``, every run folder and its log are
packed into ``OUT/<name>.tgz`` (one file per run: the device tool returns at most 8 files). Several runs share a GPU
when there are fewer GPUs than runs (their small kernels interleave). A summary table is printed at the end.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tarfile
import time
from pathlib import Path

from magwarp.training.paper import PAPER_RUNS as RUNS

#: the folder that holds this magwarp package (a checkout, or site-packages): the runs import the same magwarp
ROOT = Path(__file__).resolve().parent.parent.parent
DEFAULT = ("b0_ppo_starts40", "pushbox_sac", "pusht_sac", "obstacles_sac_random")


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--minutes", type=float, required=True, help="training wall-clock budget of each run")
    p.add_argument("--stop-after", type=float, default=None,
                   help="each run stops training once its process has run this many seconds (compilation included)")
    p.add_argument("--runs", default=",".join(DEFAULT), help=f"comma separated, from {', '.join(RUNS)}")
    p.add_argument("--work", default="runs", help="folder of the run folders (default runs/)")
    p.add_argument("--out", default=None, help="also pack each run as OUT/<name>.tgz")
    p.add_argument("--resume", action="store_true", help="continue runs whose checkpoint exists in WORK")
    p.add_argument("--device", default=None, help="cpu, or leave unset to spread runs over the visible GPUs")
    p.add_argument("--args", dest="script_args", default="", help="extra options for every training script")
    return p.parse_args(argv)


def main(argv=None) -> int:
    import shlex

    args = parse_args(argv)
    names = [n.strip() for n in args.runs.split(",") if n.strip()]
    unknown = [n for n in names if n not in RUNS]
    if unknown:
        raise SystemExit(f"unknown runs {unknown}; choose from {list(RUNS)}")
    work = Path(args.work).resolve()
    work.mkdir(parents=True, exist_ok=True)
    if args.device is None:
        import torch

        gpus = list(range(torch.cuda.device_count()))
        if not gpus:
            raise SystemExit("no CUDA device visible: pass --device cpu for a CPU run")
    else:
        gpus = [None]
    procs = []
    for i, name in enumerate(names):
        run = RUNS[name]
        folder = work / name
        cmd = [sys.executable, "-m", run.module, "--minutes", str(args.minutes), "--no-progress"]
        if args.stop_after is not None:
            cmd += ["--stop-after", str(args.stop_after)]
        if args.resume and (folder / "checkpoint.pt").is_file():
            cmd += ["--resume", str(folder)]
        else:
            cmd += ["--env-id", run.env_id, "--env-kwargs", run.train_json(), "--eval-env-kwargs", run.eval_json(),
                    "--out", str(folder), *run.script_args]
        env = dict(os.environ, PYTHONUNBUFFERED="1",
                   PYTHONPATH=os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
        gpu = gpus[i % len(gpus)]
        if gpu is None:
            cmd += ["--device", args.device]
        else:
            env["CUDA_VISIBLE_DEVICES"] = str(gpu)
            cmd += ["--device", "cuda:0"]
        cmd += shlex.split(args.script_args)
        log = open(work / f"{name}.log", "a")
        log.write(f"$ {' '.join(cmd)}  (GPU {gpu})\n")
        log.flush()
        print(f"[{time.strftime('%H:%M:%S')}] start {name} on {'GPU ' + str(gpu) if gpu is not None else args.device}",
              flush=True)
        procs.append((name, subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env), log))
    failed = 0
    for name, proc, log in procs:
        rc = proc.wait()
        log.close()
        failed += rc != 0
        print(f"[{time.strftime('%H:%M:%S')}] {name} finished (exit {rc})", flush=True)
    print("\n| run | env | env steps | wall (s) | train success | eval success | eval collisions/episode |")
    print("|---|---|---|---|---|---|---|")
    for name in names:
        row = _summary(work / name)
        print(f"| {name} | {RUNS[name].env_id} | {row.get('global_step', '-')} | {row.get('wall_s', '-')} | "
              f"{_pct(row.get('success_rate'))} | {_pct(row.get('eval_success_rate'))} | "
              f"{row.get('eval_collisions_per_episode', '-')} |")
        if args.out:
            Path(args.out).mkdir(parents=True, exist_ok=True)
            with tarfile.open(Path(args.out) / f"{name}.tgz", "w:gz") as tar:
                if (work / name).is_dir():
                    tar.add(work / name, arcname=name)
                if (work / f"{name}.log").is_file():
                    tar.add(work / f"{name}.log", arcname=f"{name}.log")
    return 1 if failed else 0


def _pct(v) -> str:
    return "-" if v is None else f"{100 * float(v):.2f}%"


def _summary(folder: Path) -> dict:
    policy = folder / "policy.pt"
    if not policy.is_file():
        return {}
    from magwarp.training.policy import policy_metadata

    try:
        return policy_metadata(str(policy))
    except Exception:  # noqa: BLE001 - a summary table must not fail on one unreadable run
        return {}


if __name__ == "__main__":
    sys.exit(main())
