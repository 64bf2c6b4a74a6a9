"""Cost of the sim2real actuation and sensing models (magwarp.envs.sim2real) on the trajectory-planning env:
env-steps/s with action latency, sensor models, or both, against neither, per num_envs, on CPU and CUDA.

    python benchmarks/sim2real_models.py                                   # B0 on cpu (+cuda:0), default sizes
    python benchmarks/sim2real_models.py --device cuda:0 --num-envs 4096,65536,1048576 --json out.json

Latency draws a delay in [0, num_cycles] per world at every reset (the kernels with latency compiled in); the sensor
models are a per-world bias, white noise and 2 % dropped readings on positions and velocities. ``physics ms`` is
the simulator's step alone (the graph the env replays), so the latency kernels' own cost shows there; the rest of the
difference is the models' torch work. Timing as in env_throughput.py (random actions from a bank, autoreset on,
``check_inputs`` off).
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run  # noqa: E402
from env_throughput import raw_env_row  # noqa: E402

MODELS = {
    "off": {},
    "latency": {"actuation": {"latency_range": (0, 40)}},
    "sensors": {"sensors": {"pos_bias_std": 1e-3, "vel_bias_std": 1e-3, "pos_noise_std": 1e-4, "vel_noise_std": 1e-3,
                            "dropout_prob": 0.02}},
}
MODELS["both"] = {**MODELS["latency"], **MODELS["sensors"]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: cpu, plus cuda:0 when present)")
    p.add_argument("--env", default="magwarp/TrajectoryPlanningB0-v0")
    p.add_argument("--num-envs", default=None, help="comma-separated sizes (default: 64,1024 on CPU, up to 1M on GPU)")
    p.add_argument("--models", default=",".join(MODELS), help=f"comma-separated, of {', '.join(MODELS)}")
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    unknown = [m for m in args.models.split(",") if m not in MODELS]
    if unknown:
        p.error(f"unknown model(s) {', '.join(unknown)} (known: {', '.join(MODELS)})")
    info, devices = start_run(args.device)
    rows: list[dict] = []
    for device in devices:
        sizes = ([int(s) for s in args.num_envs.split(",")] if args.num_envs else
                 ([64, 1024] if device == "cpu" else [4096, 65536, 262144, 1048576]))
        for n in sizes:
            base = None
            for model in args.models.split(","):
                res = raw_env_row(args.env, n, device, args.steps, **MODELS[model])
                base = res if model == "off" else base
                cost = None if base is None else 100.0 * (res["step_ms"] / base["step_ms"] - 1.0)
                rows.append({"env": args.env, "device": device, "num_envs": n, "models": model, "cost_pct": cost,
                             **res})
                print(f"  {device} num_envs={n} {model}: {res['env_steps_per_s']:.4g} env-steps/s", flush=True)
    columns = ["env", "device", "num_envs", "models", ("step_ms", "ms/step"), ("sim_ms", "physics ms"),
            ("env_steps_per_s", "env-steps/s"), ("cost_pct", "cost % vs off")]
    return finish(rows, columns, info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
