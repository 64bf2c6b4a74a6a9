"""A scalability study on the swarm env: throughput per mover (goals per second) and collisions per 1000 goals
against the number of movers, at a fixed density (movers per tile), for the scripted planner (one-way lanes on
layouts of 32 tiles a side or more, ORCA steering and its provably collision-free safety filter) and, with
``--policy``, a trained shared policy (``magwarp train magwarp/Swarm-v0``: one network for every mover, on local
observations, so it runs zero-shot at any size), or a residual one (``magwarp/SwarmResidual-v0``: a learned
correction to the planner's action, with the shield on).

Each size runs one world of a full square grid for ``--seconds`` of simulated time from a fresh reset (the same
worlds for both); the plot (PNG) and the printed table are what a scalability study reports. The policy runs on
the env it was trained on (its file's env id and evaluation options, as ``magwarp eval`` rebuilds it: a residual
policy on the residual env, which runs the planner), built with the planner row's size, layout and seed; a residual
env's planner takes ``--traffic`` unless the policy's options set its traffic rule. A zero correction is the planner
run through the residual env's shield: the planner row's run until the shield first changes one of the planner's
commands (rarely, e.g. one it cannot reach within ``a_max``), after which the two runs part (64 and 256 movers, 10 s,
CPU: 121 and 209 goals against the planner row's 123 and 199).

    python examples/swarm_scaling.py                                    # 16 .. 1024 movers, 10 s each (CPU: minutes)
    python examples/swarm_scaling.py --movers 16 64 --seconds 2 --png /tmp/swarm.png
    python examples/swarm_scaling.py --device cuda:0 --movers 256 1024 4096 16384
    python examples/swarm_scaling.py --device cuda:0 --movers 64 256 1024 4096 --policy runs/swarm_ippo/policy.pt
    python examples/swarm_scaling.py --device cuda:0 --movers 256 1024 4096 --policy runs/swarm_residual/policy.pt
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time

from magwarp.layout import Layout
from magwarp.swarm import SwarmEnv, SwarmPlanner, run_policy


def policy_env_options(policy: str, traffic: str) -> tuple[str, dict]:
    """The env id and options a policy file was trained for (its ``eval_env_kwargs``, else ``env_kwargs``, as
    ``magwarp eval`` applies them), without the size (``num_movers``, ``layout``, ``occupancy``: the study's). A
    residual env's planner takes ``traffic`` unless the options set it. A file without metadata acts on the plain
    swarm env."""
    from magwarp.envs.residual import ResidualAction
    from magwarp.registration import _load, env_ids
    from magwarp.training.common import parse_env_kwargs
    from magwarp.training.policy import policy_metadata

    path = os.path.join(policy, "policy.pt") if os.path.isdir(policy) else policy
    try:
        meta = policy_metadata(path)
    except Exception:  # noqa: BLE001 - not a TorchScript file (a torch.save'd module): it names no env
        meta = {}
    env_id = meta.get("env_id") or "magwarp/Swarm-v0"
    cls = _load(env_ids()[env_id][0]) if env_id in env_ids() else None
    if cls is None or not issubclass(cls, SwarmEnv):
        raise SystemExit(f"--policy {policy}: trained on {env_id}, not a swarm env (magwarp/Swarm-v0 and its variants)")
    stored = meta.get("eval_env_kwargs") or meta.get("env_kwargs")
    options = parse_env_kwargs(stored if isinstance(stored, str) or stored is None else json.dumps(stored))
    for size in ("num_movers", "layout", "occupancy"):
        options.pop(size, None)
    if issubclass(cls, ResidualAction):
        options["planner"] = {"traffic": traffic, **(options.get("planner") or {})}
    return env_id, options


def policy_env(policy: str, movers: int, side: int, device: str | None, seed: int, traffic: str = "auto",
               env_kwargs: dict | None = None):
    """``policy`` (a ``policy.pt``, run folder or ``pretrained:NAME``) loaded onto one world of the env it was trained
    on (:func:`policy_env_options`, then ``env_kwargs`` over them), ``movers`` movers on ``side`` x ``side`` tiles:
    ``(env, net)``."""
    import gymnasium as gym

    from magwarp.training.policy import load_policy
    from magwarp.training.pretrained import resolve_policy

    policy = resolve_policy(policy)  # pretrained:NAME -> the shipped file
    env_id, options = policy_env_options(policy, traffic)
    options.update(env_kwargs or {})
    print(f"policy {policy}: on {env_id} with {options or 'its default options'}", flush=True)
    env = gym.make_vec(env_id, num_envs=1, device=device, seed=seed, check_inputs=False, num_movers=movers,
                       layout=Layout.grid(side, side), **options).unwrapped
    return env, load_policy(policy, env.device)


def study(movers: list[int], occupancy: float, seconds: float, device: str | None, policy: str | None = None,
          traffic: str = "auto", window: float = 0.0, env_kwargs: dict | None = None, seed: int = 0,
          planner: bool = True) -> list[dict]:
    """One row per size and controller; ``window`` > 0 (simulated seconds): also the goals of each such window
    (``goals_per_window``); ``env_kwargs``: options of the policy's env over those it was trained with; ``seed``:
    the worlds' seed (the same for every controller: the same starts and goal streams until they part); ``planner``:
    also the planner's row (False: the policy's alone, e.g. when the planner's row of that seed is at hand)."""
    rows = []
    if policy is not None:
        import torch

        from magwarp.envs.residual import ResidualAction
    for m in movers:
        side = int(math.ceil(math.sqrt(m / occupancy)))
        env = SwarmEnv(1, num_movers=m, layout=Layout.grid(side, side), device=device, seed=seed, check_inputs=False)
        steps = max(1, int(round(seconds / (env.num_cycles * 1e-3))))
        win = max(1, int(round(window / (env.num_cycles * 1e-3)))) if window > 0 else 0
        controllers = [("planner", SwarmPlanner(env, traffic=traffic), env)] if planner else []
        if policy is not None:
            # the env the policy was trained on, with the planner row's size, layout and seed: the same worlds
            penv, net = policy_env(policy, m, side, device, seed, traffic, env_kwargs)
            controllers.append(("residual" if isinstance(penv, ResidualAction) else "policy", net, penv))
        for name, ctrl, env in controllers:
            t = time.perf_counter()
            if name == "planner":
                res = run_policy(env, lambda obs: ctrl(), steps, window=win)
            else:
                with torch.no_grad():
                    res = run_policy(env, ctrl, steps, window=win)
            res["wall_s"] = time.perf_counter() - t
            res["tiles"] = side * side
            res["controller"] = name
            rows.append(res)
            print(f"{m:7d} movers on {side}x{side} tiles: {res['throughput_per_mover']:.4f} goals/s/mover, "
                  f"{res['collisions_per_1000_goals']:.1f} collisions per 1000 goals, {res['deadlocked']} deadlocked "
                  f"({name}, {res['wall_s']:.1f} s)", flush=True)
    return rows


def plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    for i, name in enumerate(dict.fromkeys(r.get("controller", "planner") for r in rows)):
        sel = [r for r in rows if r.get("controller", "planner") == name]
        m = [r["movers"] for r in sel]
        label = {"planner": "scripted planner", "policy": "shared policy (zero-shot)",
                 "residual": "planner + learned residual (zero-shot)"}.get(name, name)
        ax[0].plot(m, [r["throughput_per_mover"] for r in sel], "o-", color=f"C{i}", label=label)
        ax[1].plot(m, [r["collisions_per_1000_goals"] for r in sel], "o-", color=f"C{i}", label=label)
    ax[0].set(xscale="log", xlabel="movers per world", ylabel="goals / s / mover", title="throughput per mover")
    ax[1].set(xscale="log", xlabel="movers per world", ylabel="collisions / 1000 goals", title="safety")
    ax[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print("wrote", path)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--movers", type=int, nargs="+", default=[16, 64, 256, 1024])
    p.add_argument("--occupancy", type=float, default=0.25, help="movers per tile")
    p.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per size")
    p.add_argument("--device", default=None)
    p.add_argument("--png", default="swarm_scaling.png")
    p.add_argument("--policy", default=None, help="a trained policy.pt (or run folder) to compare with the planner")
    p.add_argument("--traffic", default="auto", choices=("auto", "lanes", "free"),
                   help="the planner's traffic rule (auto: one-way lanes on layouts of 32 tiles a side or more)")
    args = p.parse_args(argv)
    rows = study(args.movers, args.occupancy, args.seconds, args.device, args.policy, args.traffic)
    plot(rows, args.png)


if __name__ == "__main__":
    main()
