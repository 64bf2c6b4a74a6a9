"""Where a trajectory-planning policy collides: collisions, timeouts and goals by the episode's age.

Runs each policy file deterministically on its own evaluation options (the ``eval_env_kwargs`` it records, as
``magwarp eval`` does) for ``--steps`` batched steps of ``--num-envs`` worlds, and counts, per bin of "steps since
the episode started", the env steps, collisions (episodes terminated), timeouts and reached goals. ``magwarp eval``
starts every world afresh for a 10 s run, so a policy that collides right after a start is penalised there far more
than in a long training episode; this table shows whether it does.

    python benchmarks/collisions_by_age.py --policy magwarp/pretrained/b0_ppo.pt --device cpu --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import common  # noqa: E402 - the benchmarks' shared plumbing, beside this file

BINS = (0, 3, 10, 30, 100)  # lower edges of the age bins, in env steps since the episode started


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", nargs="+", required=True, help="policy files (magwarp's policy.pt format)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--num-envs", type=int, default=4096)
    p.add_argument("--steps", type=int, default=400, help="batched env steps per policy")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--json", default=None, help="write the rows (with device, date, versions, command) as JSON")
    return p.parse_args(argv)


def count_by_age(policy_path: str, device: str, num_envs: int, steps: int, seed: int) -> list[dict]:
    import torch

    from magwarp.training import make_env
    from magwarp.training.policy import policy_metadata

    meta = policy_metadata(policy_path)
    env_kwargs = json.loads(meta.get("eval_env_kwargs") or meta.get("env_kwargs") or "{}")
    env, _ = make_env(meta["env_id"], num_envs, device, seed, env_kwargs)
    policy = torch.jit.load(policy_path, map_location=device).eval()
    edges = torch.tensor(BINS[1:], device=device)
    n = len(BINS)
    sums = {k: torch.zeros(n, dtype=torch.float64, device=device)
            for k in ("steps", "collisions", "timeouts", "goals")}
    age = torch.zeros(num_envs, dtype=torch.long, device=device)
    obs, _ = env.reset(seed=seed)
    with torch.no_grad():
        for _ in range(steps):
            obs, _, terminated, truncated, info = env.step(policy(obs))
            b = torch.bucketize(age, edges, right=True)  # the bin of the step just taken
            for key, value in (("steps", torch.ones_like(age)), ("collisions", terminated),
                               ("timeouts", truncated & ~terminated), ("goals", info["goals_reached"].sum(1))):
                sums[key].index_add_(0, b, value.to(torch.float64))
            age = torch.where(terminated | truncated, torch.zeros_like(age), age + 1)
    labels = [f"{BINS[i]}-{BINS[i + 1] - 1}" for i in range(n - 1)] + [f"{BINS[-1]}+", "all"]
    counts = {k: [*v.tolist(), float(v.sum())] for k, v in sums.items()}  # per bin, then the whole run
    return [{"policy": policy_path, "env_kwargs": env_kwargs, "age_bin": label,
             **{k: int(v[i]) for k, v in counts.items()},
             "collisions_per_step": counts["collisions"][i] / max(counts["steps"][i], 1),
             "goals_per_step": counts["goals"][i] / max(counts["steps"][i], 1)}
            for i, label in enumerate(labels)]


# the table of one policy (report.py prints one per policy); the printed table leads with the policy
AGE_COLUMNS = [("age_bin", "steps since start"), ("steps", "env steps"), ("goals", "goals"),
               ("collisions", "collisions"), ("collisions_per_step", "collisions per step"), ("timeouts", "timeouts"),
               ("goals_per_step", "goals per step")]


def main(argv=None) -> int:
    args = parse_args(argv)
    for path in args.policy:
        if not os.path.isfile(path):
            raise SystemExit(f"no policy file at {path!r}")
    info = common.machine_info(args.device)
    print(common.header_line(info))
    print(f"# {args.num_envs} worlds x {args.steps} steps per policy, deterministic actions, seed {args.seed}")
    rows = []
    for path in args.policy:
        rows += [{**r, "num_envs": args.num_envs, "total_steps": args.steps, **common.provenance(info)}
                 for r in count_by_age(path, args.device, args.num_envs, args.steps, args.seed)]
    common.print_table(rows, [("policy", "policy"), *AGE_COLUMNS])
    if args.json:
        common.write_json(args.json, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
