"""Levitation: a trained policy against the scripted PD baseline on the same worlds: tracking error, copper energy.

    python benchmarks/levitation_policy.py --policy runs/lev/policy.pt --device cuda:0 --envs 1024 \
        --json benchmarks/results/levitation_policy_h100.json
    python benchmarks/levitation_policy.py --envs 8 --steps 50                 # the baseline alone (a smoke run)

Every controller runs one episode of ``--steps`` env steps (default: the env's ``max_episode_steps``, 500 = 0.5 s)
in ``--envs`` worlds of the same env, reset with the same ``--seed``: the same starts and setpoints for everyone,
no autoreset. The env is the policy's own (``env_id`` and ``env_kwargs`` stored in ``policy.pt`` by ``magwarp
train``; ``--env-id`` / ``--env-kwargs`` override them; reward options do not change what is measured).

The baseline is :class:`magwarp.policies.levitation.LevitationPD` (a PD law through the least-loss commutation,
critically damped): the shipped one (15 Hz) and a sweep of its natural frequency (``--pd-frequencies``), in the
policy's action mode, plus the shipped one in the other action mode for information (``currents``: the
commutation gets the PD's whole wrench; ``wrench``: the env's action clips it at ``wrench_scale``). For a policy of
``magwarp/LevitationResidual-v0`` (a correction to the PD's action) the PD rows are that env's zero action with
the shipped PD's acceleration limits; a policy whose base PD was retuned (``pd_frequency`` and ``pd_max_acc`` off
the sweep) gets one more row, its base alone, with that base's own verdict printed for information.

Per controller, over every world: ``failed`` (share terminated: gap, tilt or distance out of bounds) and
``success`` (not failed and, at the end, position error <= ``--success-pos`` and rotation error <=
``--success-rot``). Over the ``compared`` worlds (those no controller failed, so that every row covers the same
flights): tracking error as RMS over the episode (``pos_rms_mm``, ``rot_rms_mrad``), over its second half
(``pos_settled_mm``: the steady state) and at its end (``pos_final_mm``, ``rot_final_mrad``, means), copper energy
per episode (``energy_j``, J) and mean copper loss (``loss_w``, W).

Verdict (``--tracking``: ``rms`` (default), ``settled`` or ``final``): the policy beats the baseline when either

* against the shipped PD: it spends less energy (by at least ``--margin``, default 1%), fails no more often,
  succeeds at least as often, and its position and rotation errors are at most the PD's times ``1 + --tolerance``
  (default 0: equal or better); or
* at equal tracking error: it spends less energy (by ``--margin``) than the PD retuned to the policy's position
  error (the sweep's energy and rotation error interpolated linearly in its position error; a policy that tracks
  better than every PD row is compared with the best-tracking one, one that tracks worse than every row is not
  beaten), with no worse rotation error than that retuned PD, and fails no more often than the shipped PD.

The margin keeps noise out of the verdict: a PD nudged along its own energy-vs-error curve moves a few tenths of a
percent, and the curve is convex, so the interpolated chord lies a little above it.
The last line printed says which (``VERDICT: ...``); the JSON rows carry ``verdict``, ``verdict_shipped`` and
``verdict_retuned``.
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

COLUMNS = ["controller", "action", "worlds", "steps", "compared", "failed", "success", ("pos_rms_mm", "pos RMS mm"),
           ("pos_settled_mm", "settled mm"), ("pos_final_mm", "final mm"), ("rot_rms_mrad", "rot RMS mrad"),
           ("rot_final_mrad", "rot final mrad"), ("energy_j", "energy J"), ("loss_w", "loss W"),
           ("steps_per_s", "env-steps/s")]
SHIPPED_HZ = 15.0  # LevitationPD's default natural frequency: the shipped baseline
TRACKING = {"rms": ("pos_rms_mm", "rot_rms_mrad"), "settled": ("pos_settled_mm", "rot_settled_mrad"),
            "final": ("pos_final_mm", "rot_final_mrad")}


def episode(env, controller, seed: int, steps: int) -> dict:
    """One episode of ``steps`` in every world of ``env`` (built with ``autoreset=False``) under ``controller``:
    per-world tensors (sums of squared errors while flying, flown steps, energy until a failure, final errors)."""
    import torch

    obs, _ = env.reset(seed=seed)
    n, dev = env.num_envs, env.device
    alive = torch.ones(n, dtype=torch.bool, device=dev)
    w = {k: torch.zeros(n, dtype=torch.float64, device=dev)
         for k in ("pos", "rot", "pos2", "rot2", "flown", "flown2", "energy")}
    e0 = env.energy.clone()
    half = steps // 2
    pos = rot = torch.zeros(n, dtype=torch.float64, device=dev)
    start = time.perf_counter()
    with torch.no_grad():
        for t in range(steps):
            obs, _, terminated, _, info = env.step(controller(obs))
            pos, rot = info["pos_error"].double(), info["rot_error"].double()
            a = alive.double()
            w["pos"] += a * pos.square()
            w["rot"] += a * rot.square()
            w["flown"] += a
            if t >= half:
                w["pos2"] += a * pos.square()
                w["rot2"] += a * rot.square()
                w["flown2"] += a
            w["energy"] = torch.where(alive, (env.energy - e0).double(), w["energy"])
            alive = alive & ~terminated
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)
    w.update(alive=alive, pos_final=pos, rot_final=rot, seconds=time.perf_counter() - start,
             step_s=env.num_cycles * env.dt, steps=steps)
    return w


def summarise(w: dict, common, success_pos: float, success_rot: float) -> dict:
    """A row: failures and successes over every world; tracking error and energy over the worlds in ``common`` (those
    that no controller failed, so that everyone's figures cover the same flights)."""
    n = len(w["alive"])
    success = w["alive"] & (w["pos_final"] <= success_pos) & (w["rot_final"] <= success_rot)

    def rms(key: str, count: str) -> float:
        c = float(w[count][common].sum())
        return 1e3 * math.sqrt(float(w[key][common].sum()) / c) if c else math.nan

    def mean(x) -> float:
        return float(x[common].mean()) if bool(common.any()) else math.nan

    energy = mean(w["energy"])
    return {"worlds": n, "steps": w["steps"], "compared": int(common.sum()),
            "failed": float((~w["alive"]).double().mean()),
            "success": float(success.double().mean()), "pos_rms_mm": rms("pos", "flown"),
            "pos_settled_mm": rms("pos2", "flown2"), "pos_final_mm": 1e3 * mean(w["pos_final"]),
            "rot_rms_mrad": rms("rot", "flown"), "rot_settled_mrad": rms("rot2", "flown2"),
            "rot_final_mrad": 1e3 * mean(w["rot_final"]), "energy_j": energy,
            "loss_w": energy / (w["steps"] * w["step_s"]), "steps_per_s": n * w["steps"] / w["seconds"]}


def verdict(policy: dict, baseline: dict, tracking: str, tolerance: float, margin: float = 0.0) -> tuple[bool, str]:
    """Whether ``policy`` beats ``baseline`` on energy (by at least the share ``margin``) at equal (or better)
    tracking error, and why."""
    pos_key, rot_key = TRACKING[tracking]
    tol = 1.0 + tolerance
    checks = {
        f"less energy (by {margin:.0%} or more)": policy["energy_j"] < baseline["energy_j"] * (1.0 - margin),
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


def sweep_verdict(policy: dict, sweep: list[dict], shipped: dict, tracking: str,
                  margin: float = 0.0) -> tuple[bool, str]:
    """Whether ``policy`` spends less energy than the PD retuned to its tracking error: the PD's energy and rotation
    error interpolated (linearly, in its position error) along its frequency sweep at the policy's position error.
    Outside the sweep's range: beaten only when the policy tracks better than every PD row and spends less than
    the best-tracking one. The policy must also fail no more often than the shipped PD, and spend at least the
    share ``margin`` less (the energy-vs-error curve is convex, so its chords lie a little above it)."""
    pos_key, rot_key = TRACKING[tracking]
    pts = sorted((r[pos_key], r["energy_j"], r[rot_key], r["frequency_hz"]) for r in sweep
                 if math.isfinite(r[pos_key]))
    x = policy[pos_key]
    if not pts or not math.isfinite(x):
        return False, "no finite tracking errors to compare"
    if x < pts[0][0]:
        energy, rot, where = pts[0][1], pts[0][2], f"tracks better than every PD (best: {pts[0][3]:g} Hz)"
    elif x > pts[-1][0]:
        return False, (f"position {tracking} error {x:.4g} mm is worse than every PD row (the worst: "
                       f"{pts[-1][0]:.4g} mm at {pts[-1][3]:g} Hz)")
    else:
        k = max(i for i in range(len(pts)) if pts[i][0] <= x)
        k = min(k, len(pts) - 2) if len(pts) > 1 else 0
        (x0, e0, r0, f0), (x1, e1, r1, f1) = pts[k], pts[min(k + 1, len(pts) - 1)]
        t = 0.0 if x1 == x0 else (x - x0) / (x1 - x0)
        energy, rot = e0 + t * (e1 - e0), r0 + t * (r1 - r0)
        where = f"between the {f0:g} and {f1:g} Hz PDs"
    checks = {f"less energy (by {margin:.0%} or more)": policy["energy_j"] < energy * (1.0 - margin),
              f"rotation {tracking} error": policy[rot_key] <= rot,
              "no more failures than the shipped PD": policy["failed"] <= shipped["failed"]}
    failed = [k for k, ok in checks.items() if not ok]
    why = (f"energy {policy['energy_j']:.4g} J vs {energy:.4g} J for a PD with the same position {tracking} error "
           f"{x:.4g} mm ({where}); rotation {policy[rot_key]:.4g} vs {rot:.4g} mrad")
    return not failed, why + ("" if not failed else f"; not met: {', '.join(failed)}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default=None,
                   help="policy.pt (or its run folder) from magwarp train; none: the baseline alone")
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
    p.add_argument("--margin", type=float, default=0.01,
                   help="the policy must spend at least this share less energy (default 0.01: 1%%; smaller "
                        "differences are what a PD perturbed along its own energy-vs-error curve gives)")
    p.add_argument("--pd-frequencies", default="8,10,12,15,20",
                   help=f"natural frequencies (Hz) of the PD sweep in the policy's action mode (the shipped baseline: "
                        f"{SHIPPED_HZ:g} Hz, always run)")
    p.add_argument("--json", default=None, help="write the rows (with device, date, versions, command) here")
    args = p.parse_args(argv)
    try:
        freqs = sorted({float(f) for f in args.pd_frequencies.split(",") if f.strip()} | {SHIPPED_HZ})
    except ValueError:
        p.error(f"--pd-frequencies must be numbers separated by commas, got {args.pd_frequencies!r}")
    if not all(math.isfinite(f) and f > 0 for f in freqs):
        p.error(f"--pd-frequencies must be positive, got {args.pd_frequencies!r}")
    if args.envs < 1 or (args.steps is not None and args.steps < 2):
        p.error(f"--envs must be >= 1 and --steps >= 2, got {args.envs} and {args.steps}")
    if not (args.tolerance >= 0 and math.isfinite(args.tolerance)):
        p.error(f"--tolerance must be a finite number >= 0, got {args.tolerance}")
    if not 0 <= args.margin < 1:
        p.error(f"--margin must be a share in [0, 1), got {args.margin}")

    info, _ = common.start_run(args.device)
    import gymnasium as gym
    import torch

    import magwarp  # noqa: F401  (registers the ids)
    from magwarp.envs.levitation_residual import LevitationResidualEnv
    from magwarp.evaluate import load_policy
    from magwarp.policies.levitation import DEFAULT_MAX_ACC, LevitationPD
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

    def make(action: str | None = None, **extra):
        options = {**kwargs, **({"action": action} if action else {}), **extra}
        return gym.make_vec(env_id, num_envs=args.envs, device=args.device, autoreset=False, **options)

    probe = make()
    steps = args.steps or probe.max_episode_steps
    mode = probe.action_mode
    other_mode = "currents" if mode == "wrench" else "wrench"
    residual = isinstance(probe, LevitationResidualEnv)
    envs = {mode: probe}

    def run_pd(action: str, frequency: float, max_acc=DEFAULT_MAX_ACC) -> dict:
        if residual:  # the residual env's zero action is its PD (of its pd_frequency and pd_max_acc)
            env = make(action, pd_frequency=frequency, pd_max_acc=list(max_acc))
            zero = torch.zeros((env.num_envs, *env.single_action_space.shape), device=env.device)
            return episode(env, lambda obs: zero, args.seed, steps)
        if action not in envs:
            envs[action] = make(action)
        return episode(envs[action], LevitationPD(envs[action], frequency=frequency), args.seed, steps)

    results = [({"controller": f"PD {f:g} Hz", "action": mode, "frequency_hz": f}, run_pd(mode, f)) for f in freqs]
    base = (probe.pd_frequency, tuple(probe.pd_max_acc)) if residual else None
    if base is not None and base[1] != tuple(DEFAULT_MAX_ACC):  # a retuned base: its zero action, for information
        results.append(({"controller": f"PD {base[0]:g} Hz, max_acc {base[1][0]:g}/{base[1][1]:g} (policy's base)",
                         "action": mode, "frequency_hz": None}, run_pd(mode, *base)))
    results.append(({"controller": f"PD {SHIPPED_HZ:g} Hz", "action": other_mode, "frequency_hz": SHIPPED_HZ},
                    run_pd(other_mode, SHIPPED_HZ)))
    if path:
        policy = load_policy(path, probe, trusted=False)
        name = f"policy {os.path.basename(os.path.dirname(os.path.abspath(path)))}"
        results.append(({"controller": name, "action": mode, "frequency_hz": None},
                        episode(probe, policy, args.seed, steps)))
    common_worlds = torch.stack([w["alive"] for _, w in results]).all(0)
    extra = {"env_id": env_id, "env_kwargs": kwargs, "seed": args.seed, "tracking": args.tracking,
             "tolerance": args.tolerance, "policy": path}
    rows = [{**label, **summarise(w, common_worlds, args.success_pos, args.success_rot), **extra}
            for label, w in results]
    common.finish(rows, COLUMNS, info, None)
    print(f"tracking error and energy over the {int(common_worlds.sum())} of {args.envs} worlds that no controller "
          f"failed; failed and success over all")
    if path:
        pol = rows[-1]
        sweep = [r for r in rows if r["action"] == mode and r["frequency_hz"] is not None]
        shipped = next(r for r in sweep if r["frequency_hz"] == SHIPPED_HZ)
        direct = verdict(pol, shipped, args.tracking, args.tolerance, args.margin)
        retuned = sweep_verdict(pol, sweep, shipped, args.tracking, args.margin)
        print(f"against the shipped PD ({SHIPPED_HZ:g} Hz, {mode} action): "
              f"{'beats it' if direct[0] else 'does not beat it'}: {direct[1]}")
        print(f"against the PD retuned to the policy's tracking error ({mode} action, frequencies "
              f"{', '.join(f'{f:g}' for f in freqs)} Hz): {'beats it' if retuned[0] else 'does not beat it'}: "
              f"{retuned[1]}")
        info_row = verdict(pol, rows[-2], args.tracking, args.tolerance, args.margin)
        if len(rows) > len(sweep) + 2:  # the policy's retuned base PD alone (its zero action), for information
            alone = verdict(rows[-3], shipped, args.tracking, args.tolerance, args.margin)
            print(f"(for information, the policy's base PD alone ({rows[-3]['controller']}) against the shipped PD: "
                  f"{'beats it' if alone[0] else 'does not beat it'}: {alone[1]})")
        print(f"(for information, against the shipped PD in the {other_mode} action: "
              f"{'beats it' if info_row[0] else 'does not beat it'}: {info_row[1]})")
        beats = direct[0] or retuned[0]
        for r in rows:
            r.update(verdict=beats, verdict_shipped=direct[0], verdict_retuned=retuned[0])
        how = "against the shipped PD" if direct[0] else "against the retuned PD" if retuned[0] else "neither way"
        print(f"VERDICT: policy beats baseline on energy at equal (or better) tracking error: "
              f"{'YES' if beats else 'NO'} ({how}; {args.tracking} error, tolerance {args.tolerance:g}, energy "
              f"margin {args.margin:g})")
    if args.json:
        stamp = common.provenance(info)
        common.write_json(args.json, [{**r, **stamp} for r in rows])
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
