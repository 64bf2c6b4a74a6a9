"""PPO on a batched magwarp env, torch-native and CleanRL-style (one file, read top to bottom).

The whole rollout stays on the env's device: thousands of worlds step together, observations are normalised with
running statistics, and episodes follow Gymnasium: ``terminated`` ends the return, ``truncated`` bootstraps from the
value of the episode's last observation (``info["final_obs"]``, since the env resets in the same step).

    python -m magwarp.training.ppo --env-id magwarp/TrajectoryPlanningB0-v0 --device cuda --minutes 15 --out runs/b0_ppo
    python -m magwarp.training.ppo --resume runs/b0_ppo --minutes 5          # continue the same run
    magwarp train magwarp/TrajectoryPlanningB0-v0 --algo ppo --minutes 15     # the same, through the CLI
    torchrun --standalone --nproc-per-node 4 -m magwarp.training.ppo --env-id ...   # 4 GPUs (--num-envs per GPU)

Writes under ``--out``: ``progress.csv`` (+ ``tb/`` with ``--tensorboard``), ``curve.png``, ``checkpoint.pt``
(resume), ``policy.pt`` (TorchScript; ``magwarp eval`` and ``magwarp export`` load it: see
:mod:`magwarp.training.policy`) and ``run.json`` (summary, time to target: :mod:`magwarp.training.loop`).
Under torchrun (:mod:`magwarp.training.distributed`) gradients are averaged over the ranks and rank 0 writes the files.
"""

from __future__ import annotations

import argparse
import os
import sys

import torch
from torch import nn

from magwarp.training import distributed as dist
from magwarp.training.common import RunningMeanStd, flatten_obs, load_checkpoint, save_checkpoint
from magwarp.training.loop import Session, add_run_args, entry_point, open_env, resolve_run_args, run_training
from magwarp.training.policy import mlp, save_policy

DEFAULT_ENV = "magwarp/TrajectoryPlanningB0-v0"

# Hyper-parameters per task family (any option given on the command line wins). Tuned for thousands of worlds on
# one GPU; "default" is used for env ids that match no family.
PRESETS = {
    "default": dict(num_envs=4096, num_steps=32, num_minibatches=4, update_epochs=5, lr=3e-4, gamma=0.99,
                    gae_lambda=0.95, ent_coef=0.0, hidden="256,256,128", init_log_std=-0.5, desired_kl=0.01),
    "TrajectoryPlanning": dict(num_envs=4096, num_steps=32, gamma=0.99, hidden="256,256,128"),
    "Push": dict(num_envs=4096, num_steps=25, gamma=0.97, hidden="256,256,128"),
    # swarms train on the flat agent view: num_envs worlds x num_movers agents (64 x 64 = 4096 by default)
    "Swarm": dict(num_envs=64, num_steps=32, gamma=0.98, hidden="256,256"),
}


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_args(p, DEFAULT_ENV, "ppo")
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
    return p.parse_args(argv)


def resolve_args(args: argparse.Namespace) -> argparse.Namespace:
    """Fill unset options: from the checkpoint when resuming, then the task preset, then the defaults."""
    return resolve_run_args(args, PRESETS, DEFAULT_ENV, "ppo")


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
    """PPO: train until the budget is spent; returns the summary (final success rate, env steps, wall seconds,
    time to target). Under torchrun, every rank calls this (see :mod:`magwarp.training.distributed`)."""
    return run_training(args, resolve_args, _train)


def _train(args: argparse.Namespace) -> dict:
    main_rank, world = dist.is_main(), dist.world_size()
    seed, env, base, n_obs, n_act, action_scale = open_env(args)
    device = base.device  # the env's device, with its index (cuda -> cuda:0)
    N, T = env.num_envs, args.num_steps  # sub-envs: the worlds, or every mover of every world (swarms' agent view)
    hidden = [int(h) for h in str(args.hidden).split(",")]

    agent = Agent(n_obs, n_act, hidden, args.init_log_std).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.lr, eps=1e-5)
    obs_rms = RunningMeanStd(n_obs, device, clip=10.0)
    ret_rms = RunningMeanStd(1, device)
    global_step, iteration, wall_before, lr, target_state = 0, 0, 0.0, args.lr, None
    if args.resume:
        ckpt = load_checkpoint(args.resume, device)
        agent.load_state_dict(ckpt["agent"])
        optimizer.load_state_dict(ckpt["optimizer"])
        obs_rms.load_state_dict(ckpt["obs_rms"])
        ret_rms.load_state_dict(ckpt["ret_rms"])
        global_step, iteration, wall_before, lr = ckpt["global_step"], ckpt["iteration"], ckpt["wall_s"], ckpt["lr"]
        target_state = ckpt.get("target")
        if main_rank:
            print(f"resumed from {args.resume} at step {global_step:,} (iteration {iteration})")
    dist.broadcast_([*agent.parameters(), *agent.buffers()])  # every rank starts from rank 0's weights

    # Rollout storage, on the device.
    b_obs = torch.zeros(T, N, n_obs, device=device)
    b_act = torch.zeros(T, N, n_act, device=device)
    b_logp = torch.zeros(T, N, device=device)
    b_rew = torch.zeros(T, N, device=device)
    b_done = torch.zeros(T, N, device=device)
    b_val = torch.zeros(T, N, device=device)
    disc_return = torch.zeros(N, device=device)
    session = Session(args, "ppo", device, target_state, num_agents=N)
    tracker = session.tracker
    # One step before the clock starts: kernels compile and the step graph is captured (minutes on a cold cache).
    env.reset(seed=seed)
    env.step(torch.zeros(N, n_act, device=device))

    def act(o):  # the deterministic policy (what policy.pt runs)
        return agent.actor_mean(obs_rms.normalize(flatten_obs(o))).clamp(-1.0, 1.0) * action_scale

    def save_all(summary: dict | None = None) -> None:
        dist.check_in_sync([*agent.parameters(), *obs_rms.buffers()])  # torchrun: every rank holds rank 0's
        if not main_rank:
            return
        state = {"algo": "ppo", "args": {k: v for k, v in vars(args).items() if k != "resume"},
                 "agent": agent.state_dict(), "optimizer": optimizer.state_dict(), "obs_rms": obs_rms.state_dict(),
                 "ret_rms": ret_rms.state_dict(), "global_step": global_step, "iteration": iteration,
                 "wall_s": session.timer.total, "lr": lr, "target": session.target.state()}
        save_checkpoint(os.path.join(args.out, "checkpoint.pt"), state)
        save_policy(os.path.join(args.out, "policy.pt"), agent.actor_mean, obs_rms, action_scale, squash="clip",
                    env_id=args.env_id, metadata={"algo": "ppo", "env_kwargs": args.env_kwargs,
                                                  "eval_env_kwargs": args.eval_env_kwargs,
                                                  "global_step": global_step, "wall_s": session.timer.total,
                                                  **(summary or {})})

    obs, _ = env.reset(seed=seed)
    raw = flatten_obs(obs)
    obs_rms.update(raw)
    next_obs = obs_rms.normalize(raw)
    stop = session.start(wall_before, global_step)
    while not stop:
        # ---------------------------------------------------------------- rollout (no host sync)
        with torch.no_grad():
            for t in range(T):
                b_obs[t] = next_obs
                dist_t = agent.dist(next_obs)
                action = dist_t.sample()
                b_act[t] = action
                b_logp[t] = dist_t.log_prob(action).sum(-1)
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
        global_step += N * T * world
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
                loss, kl, pg_loss, v_loss = ppo_loss(agent, args, f_obs[idx], f_act[idx], f_logp[idx], f_adv[idx],
                                                     f_ret[idx], f_val[idx])
                kls.append(kl)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                dist.average_gradients(agent.parameters())  # torchrun: the mean gradient of all ranks' minibatches
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
        if args.desired_kl > 0:  # adaptive learning rate (one host sync per iteration)
            kl_mean = float(dist.all_reduce_sum_(torch.stack(kls).mean()) / world)
            if kl_mean > 2.0 * args.desired_kl:
                lr = max(lr / 1.5, 1e-6)
            elif kl_mean < 0.5 * args.desired_kl:
                lr = min(lr * 1.5, 1e-2)
            for g in optimizer.param_groups:
                g["lr"] = lr

        # ---------------------------------------------------------------- evaluate, log, checkpoint
        stop, checkpoint = session.step_done(global_step, act, {"iteration": iteration}, lambda: {
            "lr": lr, "policy_std": float(agent.log_std.detach().exp().mean()), "loss_pg": float(pg_loss.detach()),
            "loss_v": float(v_loss.detach())})
        if checkpoint:
            save_all()
    summary = session.finish(env, act, global_step, seed, save_all, "PPO")
    env.close()
    return summary


def ppo_loss(agent: Agent, args: argparse.Namespace, obs, act, old_logp, adv, ret, old_val):
    """The clipped PPO loss of one minibatch: (loss, approximate KL, policy loss, value loss)."""
    dist_ = agent.dist(obs)
    logp = dist_.log_prob(act).sum(-1)
    log_ratio = logp - old_logp
    ratio = log_ratio.exp()
    with torch.no_grad():
        kl = ((ratio - 1) - log_ratio).mean()
    a = (adv - adv.mean()) / (adv.std() + 1e-8)
    pg_loss = torch.max(-a * ratio, -a * ratio.clamp(1 - args.clip_coef, 1 + args.clip_coef)).mean()
    v = agent.value(obs)
    v_clipped = old_val + (v - old_val).clamp(-args.clip_coef, args.clip_coef)
    v_loss = 0.5 * torch.max((v - ret).square(), (v_clipped - ret).square()).mean()
    entropy = dist_.entropy().sum(-1).mean()
    return pg_loss + args.vf_coef * v_loss - args.ent_coef * entropy, kl, pg_loss, v_loss


main = entry_point(parse_args, train)  # main(argv) -> 0, what `python -m` and torchrun run


if __name__ == "__main__":
    sys.exit(main())
