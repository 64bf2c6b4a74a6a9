"""PPO on a batched magwarp env, torch-native and CleanRL-style (one file, read top to bottom).

The whole rollout stays on the env's device: thousands of worlds step together, observations are normalised with
running statistics, and episodes follow Gymnasium: ``terminated`` ends the return, ``truncated`` bootstraps from the
value of the episode's last observation (``info["final_obs"]``, since the env resets in the same step).

    python examples/train_ppo.py --env-id magwarp/TrajectoryPlanningB0-v0 --device cuda --minutes 15 --out runs/b0_ppo
    python examples/train_ppo.py --resume runs/b0_ppo --minutes 5          # continue the same run
    magwarp train magwarp/TrajectoryPlanningB0-v0 --algo ppo --minutes 15   # the same, through the CLI

Writes under ``--out``: ``progress.csv`` (+ ``tb/`` with ``--tensorboard``), ``curve.png``, ``checkpoint.pt``
(resume) and ``policy.pt`` (TorchScript; ``magwarp eval`` and ``magwarp export`` load it: see
:mod:`magwarp.training.policy`).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import torch
from torch import nn

from magwarp.training import (CsvLogger, RunningMeanStd, SuccessTracker, Timer, evaluate, flatten_obs, load_checkpoint,
                              make_env, mlp, obs_dim, parse_env_kwargs, plot_curve, save_checkpoint, save_policy,
                              seed_everything)

# Hyper-parameters per task family (any option given on the command line wins). Tuned for thousands of worlds on
# one GPU; "default" is used for env ids that match no family.
PRESETS = {
    "default": dict(num_envs=4096, num_steps=32, num_minibatches=4, update_epochs=5, lr=3e-4, gamma=0.99,
                    gae_lambda=0.95, ent_coef=0.0, hidden="256,256,128", init_log_std=-0.5, desired_kl=0.01),
    "TrajectoryPlanning": dict(num_envs=4096, num_steps=32, gamma=0.99, hidden="256,256,128"),
    "Push": dict(num_envs=4096, num_steps=25, gamma=0.97, hidden="256,256,128"),
}


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env-id", default=None, help="magwarp env id (default: magwarp/TrajectoryPlanningB0-v0)")
    p.add_argument("--env-kwargs", default=None, help='JSON env options, e.g. \'{"layout": [[1,1],[1,1]], "num_movers": 1}\'')
    p.add_argument("--eval-env-kwargs", default=None,
                   help="JSON env options that `magwarp eval` applies to this policy (stored in policy.pt)")
    p.add_argument("--device", default=None, help="cpu or cuda[:N] (default: cuda when available)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--out", default=None, help="run folder (default: runs/<env>_ppo)")
    p.add_argument("--resume", default=None, help="checkpoint file or run folder to continue (its options are reused)")
    p.add_argument("--minutes", type=float, default=None, help="wall-clock training budget of this session")
    p.add_argument("--total-steps", type=float, default=None, help="stop after this many env steps (all worlds)")
    p.add_argument("--stop-after", type=float, default=None,
                   help="stop training once the process has run this many seconds (start-up and compilation included)")
    p.add_argument("--num-envs", type=int, default=None)
    p.add_argument("--num-steps", type=int, default=None, help="rollout length per env and iteration")
    p.add_argument("--num-minibatches", type=int, default=None)
    p.add_argument("--update-epochs", type=int, default=None)
    p.add_argument("--lr", type=float, default=None, help="initial learning rate (adapted to --desired-kl)")
    p.add_argument("--desired-kl", type=float, default=None, help="adaptive learning rate target KL (0: fixed lr)")
    p.add_argument("--gamma", type=float, default=None)
    p.add_argument("--gae-lambda", type=float, default=None)
    p.add_argument("--clip-coef", type=float, default=0.2)
    p.add_argument("--ent-coef", type=float, default=None)
    p.add_argument("--vf-coef", type=float, default=1.0)
    p.add_argument("--max-grad-norm", type=float, default=1.0)
    p.add_argument("--hidden", default=None, help="hidden layer sizes, comma separated")
    p.add_argument("--init-log-std", type=float, default=None)
    p.add_argument("--no-norm-reward", action="store_true", help="do not scale rewards by the return's running std")
    p.add_argument("--log-every", type=float, default=10.0, help="seconds between log lines")
    p.add_argument("--checkpoint-every", type=float, default=60.0, help="seconds between checkpoints")
    p.add_argument("--eval-steps", type=int, default=200,
                   help="batched steps of a final deterministic evaluation on the training env (0: none)")
    p.add_argument("--tensorboard", action="store_true", help="also log to OUT/tb (needs tensorboard)")
    p.add_argument("--no-progress", action="store_true", help="no tqdm bar")
    p.add_argument("--torch-threads", type=int, default=None,
                   help="torch CPU threads (default on a CPU device: 1, fastest for these small networks)")
    p.add_argument("--deterministic", action="store_true", help="deterministic torch algorithms (tests)")
    args = p.parse_args(argv)
    return args


def resolve_args(args: argparse.Namespace) -> argparse.Namespace:
    """Fill unset options: from the checkpoint when resuming, then the task preset, then the defaults."""
    if args.resume:
        saved = load_checkpoint(args.resume, "cpu")["args"]
        for k, v in saved.items():
            # stop_after: a limit of the earlier process, not of this one; out: a run continues where its checkpoint
            # is now (a copied or moved folder), not in the folder it was first written to
            if k in ("stop_after", "out"):
                continue
            if getattr(args, k, None) is None:
                setattr(args, k, v)
        if args.out is None:
            args.out = args.resume if os.path.isdir(args.resume) else os.path.dirname(args.resume)
    args.env_id = args.env_id or "magwarp/TrajectoryPlanningB0-v0"
    family = next((k for k in PRESETS if k != "default" and k in args.env_id), "default")
    for k, v in {**PRESETS["default"], **PRESETS[family]}.items():
        if getattr(args, k, None) is None:
            setattr(args, k, v)
    if args.device is None:
        args.device = "cuda" if torch.cuda.is_available() else "cpu"
    args.seed = 0 if args.seed is None else args.seed
    args.out = args.out or os.path.join("runs", args.env_id.split("/")[-1] + "_ppo")
    parse_env_kwargs(args.eval_env_kwargs)  # a bad JSON fails now, not when the policy is saved
    if args.minutes is None and args.total_steps is None and args.stop_after is None:
        raise ValueError("give a budget: --minutes, --total-steps and/or --stop-after")
    return args


class Agent(nn.Module):
    def __init__(self, n_obs: int, n_act: int, hidden: list[int], init_log_std: float):
        super().__init__()
        self.actor_mean = mlp(n_obs, hidden, n_act)
        self.critic = mlp(n_obs, hidden, 1)
        self.log_std = nn.Parameter(torch.full((n_act,), float(init_log_std)))
        nn.init.orthogonal_(self.actor_mean[-1].weight, 0.01)
        nn.init.zeros_(self.actor_mean[-1].bias)

    def value(self, x: torch.Tensor) -> torch.Tensor:
        return self.critic(x).squeeze(-1)

    def dist(self, x: torch.Tensor) -> torch.distributions.Normal:
        mean = self.actor_mean(x)
        return torch.distributions.Normal(mean, self.log_std.clamp(-5.0, 1.0).exp().expand_as(mean))


def train(args: argparse.Namespace) -> dict:
    """Train until the budget is spent; returns a summary (final success rate, env steps, wall seconds)."""
    args = resolve_args(args)
    threads = torch.get_num_threads()
    if args.torch_threads or str(args.device).startswith("cpu"):
        torch.set_num_threads(args.torch_threads or 1)
    try:
        return _train(args)
    finally:
        torch.set_num_threads(threads)


def _train(args: argparse.Namespace) -> dict:
    seed_everything(args.seed, args.deterministic)
    env, base = make_env(args.env_id, args.num_envs, args.device, args.seed, parse_env_kwargs(args.env_kwargs))
    device = base.device  # the env's device, with its index (cuda -> cuda:0)
    N, T = args.num_envs, args.num_steps
    n_obs, n_act = obs_dim(base.single_observation_space), int(base.single_action_space.shape[0])
    action_scale = torch.as_tensor(base.single_action_space.high, device=device, dtype=torch.float32)
    hidden = [int(h) for h in str(args.hidden).split(",")]

    agent = Agent(n_obs, n_act, hidden, args.init_log_std).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.lr, eps=1e-5)
    obs_rms = RunningMeanStd(n_obs, device, clip=10.0)
    ret_rms = RunningMeanStd(1, device)
    global_step, iteration, wall_before, lr = 0, 0, 0.0, args.lr
    os.makedirs(args.out, exist_ok=True)
    if args.resume:
        ckpt = load_checkpoint(args.resume, device)
        agent.load_state_dict(ckpt["agent"])
        optimizer.load_state_dict(ckpt["optimizer"])
        obs_rms.load_state_dict(ckpt["obs_rms"])
        ret_rms.load_state_dict(ckpt["ret_rms"])
        global_step, iteration, wall_before, lr = ckpt["global_step"], ckpt["iteration"], ckpt["wall_s"], ckpt["lr"]
        print(f"resumed from {args.resume} at step {global_step:,} (iteration {iteration})")

    # Rollout storage, on the device.
    b_obs = torch.zeros(T, N, n_obs, device=device)
    b_act = torch.zeros(T, N, n_act, device=device)
    b_logp = torch.zeros(T, N, device=device)
    b_rew = torch.zeros(T, N, device=device)
    b_done = torch.zeros(T, N, device=device)
    b_val = torch.zeros(T, N, device=device)
    disc_return = torch.zeros(N, device=device)
    tracker = SuccessTracker(N, device)
    logger = CsvLogger(args.out, args.tensorboard, resume=bool(args.resume))
    # One step before the clock starts: kernels compile and the step graph is captured (minutes on a cold cache).
    env.reset(seed=args.seed)
    env.step(torch.zeros(N, n_act, device=device))
    timer = Timer(args.minutes, wall_before, args.stop_after)
    total = None if args.total_steps is None else int(args.total_steps)

    bar = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=total if total else max(int(timer.limit), 1), unit="step" if total else "s",
                   unit_scale=bool(total), desc=f"ppo {args.env_id.split('/')[-1]}", dynamic_ncols=True,
                   mininterval=1.0)

    def save_all(summary: dict | None = None) -> None:
        state = {"algo": "ppo", "args": {k: v for k, v in vars(args).items() if k != "resume"},
                 "agent": agent.state_dict(), "optimizer": optimizer.state_dict(), "obs_rms": obs_rms.state_dict(),
                 "ret_rms": ret_rms.state_dict(), "global_step": global_step, "iteration": iteration,
                 "wall_s": timer.total, "lr": lr}
        save_checkpoint(os.path.join(args.out, "checkpoint.pt"), state)
        save_policy(os.path.join(args.out, "policy.pt"), agent.actor_mean, obs_rms, action_scale, squash="clip",
                    env_id=args.env_id, metadata={"algo": "ppo", "env_kwargs": args.env_kwargs,
                                                  "eval_env_kwargs": args.eval_env_kwargs,
                                                  "global_step": global_step, "wall_s": timer.total, **(summary or {})})

    obs, _ = env.reset(seed=args.seed)
    raw = flatten_obs(obs)
    obs_rms.update(raw)
    next_obs = obs_rms.normalize(raw)
    last_log = last_ckpt = time.perf_counter()
    steps_at_log, stats = global_step, {"success_rate": float("nan")}
    summary: dict = {}
    while not timer.expired and (total is None or global_step < total):
        # ---------------------------------------------------------------- rollout (no host sync)
        with torch.no_grad():
            for t in range(T):
                b_obs[t] = next_obs
                dist = agent.dist(next_obs)
                action = dist.sample()
                b_act[t] = action
                b_logp[t] = dist.log_prob(action).sum(-1)
                b_val[t] = agent.value(next_obs)
                obs, reward, terminated, truncated, info = env.step(action.clamp(-1.0, 1.0) * action_scale)
                tracker.update(reward, terminated, truncated, info)
                done = terminated | truncated
                raw = flatten_obs(obs)
                obs_rms.update(raw)
                next_obs = obs_rms.normalize(raw)
                # Truncation: bootstrap from the value of the finished episode's last observation.
                final_v = agent.value(obs_rms.normalize(flatten_obs(info["final_obs"])))
                reward = reward + args.gamma * final_v * (truncated & ~terminated) * (ret_rms.var.sqrt().float()
                                                                                     if not args.no_norm_reward else 1)
                if not args.no_norm_reward:  # scale by the running std of the discounted return
                    disc_return.mul_(args.gamma).add_(reward)
                    ret_rms.update(disc_return[:, None])
                    disc_return.masked_fill_(done, 0.0)
                    reward = reward / torch.sqrt(ret_rms.var + 1e-8).float()
                b_rew[t] = reward
                b_done[t] = done.float()
            # GAE over the rollout (done at t: the episode ended at step t, its bootstrap is already in the reward).
            next_value = agent.value(next_obs)
            adv = torch.zeros_like(b_rew)
            last = torch.zeros(N, device=device)
            for t in reversed(range(T)):
                nv = next_value if t == T - 1 else b_val[t + 1]
                nonterm = 1.0 - b_done[t]
                delta = b_rew[t] + args.gamma * nv * nonterm - b_val[t]
                last = delta + args.gamma * args.gae_lambda * nonterm * last
                adv[t] = last
            ret = adv + b_val
        global_step += N * T
        iteration += 1

        # ---------------------------------------------------------------- update
        f_obs, f_act, f_logp = b_obs.reshape(-1, n_obs), b_act.reshape(-1, n_act), b_logp.reshape(-1)
        f_adv, f_ret, f_val = adv.reshape(-1), ret.reshape(-1), b_val.reshape(-1)
        batch = N * T
        mb = batch // args.num_minibatches
        kls = []
        for _ in range(args.update_epochs):
            perm = torch.randperm(batch, device=device)
            for start in range(0, batch - mb + 1, mb):
                idx = perm[start:start + mb]
                dist = agent.dist(f_obs[idx])
                logp = dist.log_prob(f_act[idx]).sum(-1)
                log_ratio = logp - f_logp[idx]
                ratio = log_ratio.exp()
                with torch.no_grad():
                    kl = ((ratio - 1) - log_ratio).mean()
                    kls.append(kl)
                a = f_adv[idx]
                a = (a - a.mean()) / (a.std() + 1e-8)
                pg_loss = torch.max(-a * ratio, -a * ratio.clamp(1 - args.clip_coef, 1 + args.clip_coef)).mean()
                v = agent.value(f_obs[idx])
                v_clipped = f_val[idx] + (v - f_val[idx]).clamp(-args.clip_coef, args.clip_coef)
                v_loss = 0.5 * torch.max((v - f_ret[idx]).square(), (v_clipped - f_ret[idx]).square()).mean()
                entropy = dist.entropy().sum(-1).mean()
                loss = pg_loss + args.vf_coef * v_loss - args.ent_coef * entropy
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
        if args.desired_kl > 0:  # adaptive learning rate (one host sync per iteration)
            kl_mean = float(torch.stack(kls).mean())
            if kl_mean > 2.0 * args.desired_kl:
                lr = max(lr / 1.5, 1e-6)
            elif kl_mean < 0.5 * args.desired_kl:
                lr = min(lr * 1.5, 1e-2)
            for g in optimizer.param_groups:
                g["lr"] = lr

        # ---------------------------------------------------------------- log, checkpoint
        now = time.perf_counter()
        final = timer.expired or (total is not None and global_step >= total)
        if now - last_log >= args.log_every or final:
            stats = tracker.pop()
            sps = (global_step - steps_at_log) / max(now - last_log, 1e-9)
            row = {"global_step": global_step, "iteration": iteration, "wall_s": round(timer.total, 2),
                   "sps": round(sps), **stats, "lr": lr, "policy_std": float(agent.log_std.detach().exp().mean()),
                   "loss_pg": float(pg_loss.detach()), "loss_v": float(v_loss.detach())}
            logger.log(row)
            last_log, steps_at_log = now, global_step
            if bar is None:
                print(f"step {global_step:>12,}  {sps:>10,.0f} steps/s  success {stats['success_rate']:.3f}  "
                      f"return {stats['ep_return']:.2f}")
        if bar is not None:
            bar.n = min(global_step, total) if total else min(int(timer.elapsed), bar.total)
            bar.set_postfix_str(f"{global_step:,} steps, {global_step / max(timer.elapsed, 1e-9):,.0f} steps/s, "
                                f"success {stats['success_rate']:.3f}", refresh=False)
            bar.update(0)  # redraws at most once per mininterval
        if now - last_ckpt >= args.checkpoint_every:
            save_all()
            last_ckpt = now
    if bar is not None:
        bar.close()
    summary = {"success_rate": stats["success_rate"], "global_step": global_step, "wall_s": round(timer.total, 1)}
    if args.eval_steps > 0:  # the deterministic policy (what policy.pt runs), from fresh episodes
        def act(o):
            return agent.actor_mean(obs_rms.normalize(flatten_obs(o))).clamp(-1.0, 1.0) * action_scale

        ev = evaluate(env, act, args.eval_steps, seed=args.seed + 10_000)
        summary.update({f"eval_{k}": v for k, v in ev.items()})
        print(f"deterministic evaluation ({args.eval_steps} steps x {N} envs): success {ev['success_rate']:.4f}, "
              f"collisions/episode {ev['collisions_per_episode']:.4f}, {ev['episodes']:.0f} episodes")
    save_all(summary)
    logger.close()
    plot_curve(logger.path, os.path.join(args.out, "curve.png"), f"PPO {args.env_id} ({args.device})")
    print(f"saved {args.out}/policy.pt, checkpoint.pt, progress.csv, curve.png; "
          f"final success {stats['success_rate']:.3f}")
    env.close()
    return summary


def main(argv=None) -> int:
    train(parse_args(argv))
    return 0


if __name__ == "__main__":
    sys.exit(main())
