"""Combined plots from benchmark JSON files of several machines (e.g. the CPU run here and a GPU run elsewhere).

    python benchmarks/plots.py --scaling benchmarks/results/scaling_cpu.json benchmarks/results/scaling_gpu_vs_magbotsim.json \
        --env benchmarks/results/env_throughput_cpu.json benchmarks/results/env_throughput_gpu.json --out benchmarks/results
    python benchmarks/plots.py --time-to-target ttt_b0.json ttt_pushbox.json --out benchmarks/results/time_to_target
"""

from __future__ import annotations

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def _rows(paths: list[str], tag_engine: bool) -> list[dict]:
    rows = []
    for path in paths:
        with open(path) as f:
            for r in json.load(f):
                r = dict(r)
                # MagBotSim rows measured on different machines are different series: name the machine.
                if tag_engine and r["engine"].startswith("magbotsim"):
                    r["device"] = f"cpu of {r.get('device_name', '?')}"
                rows.append(r)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scaling", nargs="*", default=[])
    p.add_argument("--env", nargs="*", default=[])
    p.add_argument("--time-to-target", nargs="*", default=[],
                   help="benchmarks/time_to_target.py JSON files: success against seconds since process start")
    p.add_argument("--out", default=".")
    args = p.parse_args(argv)
    if args.scaling:
        import scaling

        scaling.plot(_rows(args.scaling, True), os.path.join(args.out, "scaling_cpu_gpu.png"))
    if args.env:
        import env_throughput

        env_throughput.plot(_rows(args.env, False), os.path.join(args.out, "env_throughput_cpu_gpu.png"))
    if args.time_to_target:
        import time_to_target

        rows = [r for path in args.time_to_target for r in time_to_target.read_json(path)]
        time_to_target.plot(rows, os.path.join(args.out, "time_to_target.png"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
