"""Cost of domain randomisation (magwarp.envs.randomization) on the push envs: env-steps/s with every event term on,
against none, per num_envs, on CPU and CUDA.

    python benchmarks/randomization.py                                    # Push-Box on cpu (+cuda:0), default sizes
    python benchmarks/randomization.py --device cuda:0 --num-envs 4096,16384,65536 --json out.json

``full`` randomises, at every reset, the object's mass and friction, the mover's mass and a payload on it, and every
10 steps the floor friction (all terms of a push scene without obstacles). Autoreset runs the reset hook in every
step (for the worlds that finished, often none), so the reset terms' draws and model writes are paid at every step:
that is the cost shown. Timing as in env_throughput.py (random actions from a bank, autoreset on, ``check_inputs``
off); ``raw mjw ms`` is bare mujoco-warp on the env's model for reference.
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run  # noqa: E402
from env_throughput import raw_env_row  # noqa: E402

FULL = [
    {"field": "object_mass", "dist": {"uniform": [0.2, 0.4]}},
    {"field": "object_friction", "dist": {"gaussian": [0.6, 0.1], "clip": [0.3, 0.9]}},
    {"field": "mover_mass", "dist": {"log_uniform": [0.8, 1.25]}, "op": "scale"},
    {"field": "payload_mass", "dist": {"uniform": [0.0, 0.3]}, "offset": [0.02, 0.0, 0.01]},
    {"field": "floor_friction", "dist": {"uniform": [-0.2, 0.2]}, "op": "add", "mode": "interval",
     "interval_steps": 10},
]
SETTINGS = {"off": {}, "full": {"randomization": FULL}}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: cpu, plus cuda:0 when present)")
    p.add_argument("--env", default="magwarp/PushBox-v0")
    p.add_argument("--num-envs", default=None,
                   help="comma-separated sizes (default: 64,256 on CPU, up to 65536 on GPU)")
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    info, devices = start_run(args.device)
    rows: list[dict] = []
    for device in devices:
        sizes = ([int(s) for s in args.num_envs.split(",")] if args.num_envs else
                 ([64, 256] if device == "cpu" else [4096, 16384, 65536]))
        for n in sizes:
            base = None
            for name, kwargs in SETTINGS.items():
                res = raw_env_row(args.env, n, device, args.steps, **kwargs)
                base = res if name == "off" else base
                cost = 100.0 * (res["step_ms"] / base["step_ms"] - 1.0)
                rows.append({"env": args.env, "device": device, "num_envs": n, "randomization": name,
                             "cost_pct": cost, **res})
                print(f"  {device} num_envs={n} {name}: {res['env_steps_per_s']:.4g} env-steps/s", flush=True)
    columns = ["env", "device", "num_envs", "randomization", ("step_ms", "ms/step"), ("raw_mjw_ms", "raw mjw ms"),
            ("env_steps_per_s", "env-steps/s"), ("cost_pct", "cost % vs off")]
    return finish(rows, columns, info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
