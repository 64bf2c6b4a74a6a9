"""Levitation: a trained policy against the scripted PD baseline on the same worlds: tracking error, copper energy.

    python benchmarks/levitation_policy.py --policy runs/lev/policy.pt --device cuda:0 --envs 1024 \
        --json benchmarks/results/levitation_policy_h100.json
    python benchmarks/levitation_policy.py --envs 8 --steps 50                 # the baseline alone (a smoke run)

Every controller runs one episode of ``--steps`` env steps (default: the env's ``max_episode_steps``, 500 = 0.5 s)
in ``--envs`` worlds of the same env, reset with the same ``--seed``: the same starts and setpoints for everyone,
no autoreset. The env is the policy's own (``env_id`` and ``env_kwargs`` stored in ``policy.pt`` by ``magwarp
train``; ``--env-id`` / ``--env-kwargs`` override them; reward options do not change what is measured). The
baseline is :class:`magwarp.policies.levitation.LevitationPD` (a PD law through the least-loss commutation), run in
both action modes (``currents``: the commutation gets the PD's whole wrench; ``wrench``: the env's action clips the
wrench at ``wrench_scale``) with the rest of the env's options as the policy's. For a policy of
``magwarp/LevitationResidual-v0`` (a correction to the PD's action) the baseline is the same env's zero action.

Per controller: ``failed`` (share of worlds terminated: gap, tilt or distance out of bounds), ``success`` (not
failed and, at the end, position error <= ``--success-pos`` and rotation error <= ``--success-rot``), tracking
error as RMS over every step of the episode (``pos_rms_mm``, ``rot_rms_mrad``; a failed world up to its failure),
over its second half (``pos_settled_mm``: the steady state) and at the end (``pos_final_mm``, ``rot_final_mrad``, of
the worlds that did not fail), copper energy per episode (``energy_j``, J, a failed world up to its failure) and
mean copper loss (``loss_w``, W: energy over the time flown).

Verdict: the policy beats a baseline when it spends less energy, fails no more often, succeeds at least as often,
and its tracking error (``--tracking``: ``rms`` (default), ``settled`` or ``final``; position and rotation) is at
most the baseline's times ``1 + --tolerance`` (default 0: equal or better). The line printed last says whether it
beats every baseline row.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import common  # noqa: E402

COLUMNS = ["controller", "action", "worlds", "steps", "failed", "success", ("pos_rms_mm", "pos RMS mm"),
           ("pos_settled_mm", "settled mm"), ("pos_final_mm", "final mm"), ("rot_rms_mrad", "rot RMS mrad"),
           ("rot_final_mrad", "rot final mrad"), ("energy_j", "energy J"), ("loss_w", "loss W"),
           ("steps_per_s", "env-steps/s")]
TRACKING = {"rms": ("pos_rms_mm", "rot_rms_mrad"), "settled": ("pos_settled_mm", "rot_settled_mrad"),
            "final": ("pos_final_mm", "rot_final_mrad")}


def episode(env, controller, seed: int, steps: int, success_pos: float, success_rot: float) -> dict:
    """One episode of ``steps`` in every world of ``env`` (built with ``autoreset=False``) under ``controller``."""
    import torch

    obs, _ = env.reset(seed=seed)
    n, dev = env.num_envs, env.device
    alive = torch.ones(n, dtype=torch.bool, device=dev)
    flown = torch.zeros(n, device=dev)
    sums = {k: torch.zeros(n, dtype=torch.float64, device=dev) for k in ("pos", "rot", "pos2", "rot2")}
    settled_steps = torch.zeros(n, device=dev)
    e0 = env.energy.clone()
    energy = torch.zeros(n, dtype=torch.float64, device=dev)
    half = steps // 2
    pos = rot = torch.zeros(n, device=dev)
    start = time.perf_counter()
    with torch.no_grad():
        for t in range(steps):
            obs, _, terminated, _, info = env.step(controller(obs))
            pos, rot = info["pos_error"].double(), info["rot_error"].double()
            a = alive.double()
            sums["pos"] += a * pos.square()
            sums["rot"] += a * rot.square()
            if t >= half:
                sums["pos2"] += a * pos.square()
                sums["rot2"] += a * rot.square()
                settled_steps += alive
            flown += alive
            energy = torch.where(alive, env.energy - e0, energy)
            alive = alive & ~terminated
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)
    seconds = time.perf_counter() - start
    ok = alive
    success = ok & (pos <= success_pos) & (rot <= success_rot)
    cycle_s = env.num_cycles * env.dt

    def rms(key: str, count) -> float:
        c = float(count.sum())
        return math.sqrt(float(sums[key].sum()) / c) if c else math.nan

    def final(x) -> float:
        return float(x[ok].mean()) if ok.any() else math.nan

    return {"worlds": n, "steps": steps, "failed": float((~alive).double().mean()),
            "success": float(success.double().mean()),
            "pos_rms_mm": 1e3 * rms("pos", flown), "pos_settled_mm": 1e3 * rms("pos2", settled_steps),
            "pos_final_mm": 1e3 * final(pos), "rot_rms_mrad": 1e3 * rms("rot", flown),
            "rot_settled_mrad": 1e3 * rms("rot2", settled_steps), "rot_final_mrad": 1e3 * final(rot),
            "energy_j": float(energy.mean()),
            "loss_w": float((energy / (flown.double() * cycle_s).clamp(min=1e-12)).mean()),
            "steps_per_s": n * steps / seconds}


def verdict(policy: dict, baseline: dict, tracking: str, tolerance: float) -> tuple[bool, str]:
    """Whether ``policy`` beats ``baseline`` on energy at equal (or better) tracking error, and why."""
    pos_key, rot_key = TRACKING[tracking]
    tol = 1.0 + tolerance
    checks = {
        "less energy": policy["energy_j"] < baseline["energy_j"],
        "no more failures": policy["failed"] <= baseline["failed"],
        "at least as many successes": policy["success"] >= baseline["success"],
        f"position {tracking} error": policy[pos_key] <= baseline[pos_key] * tol,
        f"rotation {tracking} error": policy[rot_key] <= baseline[rot_key] * tol,
    }
    failed = [k for k, ok in checks.items() if not ok]
    why = (f"energy {policy['energy_j']:.4g} vs {baseline['energy_j']:.4g} J, position {tracking} "
           f"{policy[pos_key]:.4g} vs {baseline[pos_key]:.4g} mm, rotation {policy[rot_key]:.4g} vs "
           f"{baseline[rot_key]:.4g} mrad, failed {policy['failed']:.3g} vs {baseline['failed']:.3g}, success "
           f"{policy['success']:.3g} vs {baseline['success']:.3g}")
    return not failed, why + ("" if not failed else f"; not met: {', '.join(failed)}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default=None, help="policy.pt (or its run folder) from magwarp train; none: baseline only")
    p.add_argument("--env-id", default=None, help="default: the policy's env id, else magwarp/Levitation-v0")
    p.add_argument("--env-kwargs", default=None, help="JSON env options (default: the policy's training options)")
    p.add_argument("--envs", type=int, default=256, help="worlds (one episode each)")
    p.add_argument("--steps", type=int, default=None, help="env steps per episode (default: max_episode_steps)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu", help="cpu or cuda:N")
    p.add_argument("--success-pos", type=float, default=5e-4, help="success: final position error (m), default 0.5 mm")
    p.add_argument("--success-rot", type=float, default=0.01, help="success: final rotation error (rad)")
    p.add_argument("--tracking", choices=sorted(TRACKING), default="rms", help="the tracking error of the verdict")
    p.add_argument("--tolerance", type=float, default=0.0,
                   help="the policy's tracking error may exceed the baseline's by this share (default 0: equal)")
    p.add_argument("--json", default=None, help="write the rows (with device, date, versions, command) here")
    args = p.parse_args(argv)
    if args.envs < 1 or (args.steps is not None and args.steps < 2):
        p.error(f"--envs must be >= 1 and --steps >= 2, got {args.envs} and {args.steps}")
    if not (args.tolerance >= 0 and math.isfinite(args.tolerance)):
        p.error(f"--tolerance must be a finite number >= 0, got {args.tolerance}")

    info, _ = common.start_run(args.device)
    import gymnasium as gym
    import torch

    import magwarp  # noqa: F401  (registers the ids)
    from magwarp.envs.levitation_residual import LevitationResidualEnv
    from magwarp.evaluate import load_policy
    from magwarp.policies.levitation import LevitationPD
    from magwarp.training.policy import policy_metadata

    path = args.policy
    if path is not None and os.path.isdir(path):
        path = os.path.join(path, "policy.pt")
    if path is not None and not os.path.isfile(path):
        p.error(f"--policy {args.policy!r}: no such file")
    meta = policy_metadata(path) if path else {}
    env_id = args.env_id or meta.get("env_id") or "magwarp/Levitation-v0"
    kwargs = json.loads(args.env_kwargs or meta.get("env_kwargs") or "{}")
    if not isinstance(kwargs, dict):
        p.error(f"--env-kwargs must be a JSON object, got {args.env_kwargs!r}")

    def make(action: str | None = None):
        options = {**kwargs, **({"action": action} if action else {})}
        return gym.make_vec(env_id, num_envs=args.envs, device=args.device, autoreset=False, **options)

    probe = make()
    steps = args.steps or probe.max_episode_steps
    mode = probe.action_mode
    def baseline(env):
        if isinstance(env, LevitationResidualEnv):  # the residual env's zero action is the PD baseline
            zero = torch.zeros((env.num_envs, *env.single_action_space.shape), device=env.device)
            return lambda obs: zero
        return LevitationPD(env)

    rows = []
    for action in ("currents", "wrench"):
        env = probe if action == mode else make(action)
        row = episode(env, baseline(env), args.seed, steps, args.success_pos, args.success_rot)
        rows.append({"controller": "PD baseline", "action": action, **row})
    if path:
        policy = load_policy(path, probe, trusted=False)
        row = episode(probe, policy, args.seed, steps, args.success_pos, args.success_rot)
        rows.append({"controller": f"policy {os.path.basename(os.path.dirname(os.path.abspath(path)))}",
                     "action": mode, **row})
    extra = {"env_id": env_id, "env_kwargs": kwargs, "seed": args.seed, "tracking": args.tracking,
             "tolerance": args.tolerance, "policy": path}
    rows = [{**r, **extra} for r in rows]
    common.finish(rows, COLUMNS, info, None)
    if path:
        results = [verdict(rows[-1], base, args.tracking, args.tolerance) for base in rows[:-1]]
        for base, (ok, why) in zip(rows[:-1], results):
            print(f"against the PD baseline ({base['action']} action): {'beats it' if ok else 'does not beat it'}: "
                  f"{why}")
        beats = all(ok for ok, _ in results)
        for r in rows:
            r["verdict"] = beats
        print(f"VERDICT: policy beats baseline on energy at equal (or better) tracking error: "
              f"{'YES' if beats else 'NO'} ({args.tracking} error, tolerance {args.tolerance:g})")
    if args.json:
        stamp = common.provenance(info)
        common.write_json(args.json, [{**r, **stamp} for r in rows])
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
