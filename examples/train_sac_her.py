"""SAC + hindsight experience replay (HER) on a batched magwarp env, torch-native and CleanRL-style (one file).

The replay buffer lives on the env's device as ``[time, env]`` rings. HER uses the *future* strategy over the episode
storage: a sampled transition of env ``e`` at time ``t`` gets, with probability ``--her-ratio``, the goal achieved at a
uniformly drawn later step of the same episode, and its reward is recomputed in one batched call of the env's
``compute_reward(achieved_goal, desired_goal, info)`` (collision flags stored with each transition stay in ``info``).
Episode ends are tracked per env without scanning the buffer, so sampling is O(batch).

    python examples/train_sac_her.py --env-id magwarp/PushBox-v0 --device cuda --minutes 15 --out runs/pushbox_sac
    python examples/train_sac_her.py --resume runs/pushbox_sac --minutes 5
    magwarp train magwarp/PushBox-v0 --algo sac-her --minutes 15

Writes under ``--out``: ``progress.csv`` (+ ``tb/``), ``curve.png``, ``checkpoint.pt`` (networks, optimisers and
normaliser; the replay buffer is not saved: a resumed run refills it) and ``policy.pt`` (TorchScript, see
:mod:`magwarp.training.policy`).
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time

import torch
import torch.nn.functional as F
from torch import nn

from magwarp.training import (OBS_KEYS, CsvLogger, RunningMeanStd, SuccessTracker, Timer, evaluate, flatten_obs,
                              load_checkpoint, make_env, mlp, obs_dim, parse_env_kwargs, plot_curve, save_checkpoint,
                              save_policy, seed_everything)

# Hyper-parameters per task family (any option given on the command line wins), for one GPU.
PRESETS = {
    "default": dict(num_envs=1024, buffer_steps=1000, batch_size=8192, updates_per_step=2, learning_starts=20,
                    gamma=0.98, tau=0.01, lr=3e-4, init_alpha=0.1, her_ratio=0.8, hidden="256,256,256", policy_delay=1),
    "TrajectoryPlanning": dict(num_envs=1024, buffer_steps=1000, gamma=0.99, her_ratio=0.5),
    "PushBox": dict(num_envs=1024, buffer_steps=1000, gamma=0.95),
    "PushWithObstacles": dict(num_envs=1024, buffer_steps=1000, gamma=0.95),
    "PushT": dict(num_envs=1024, buffer_steps=1000, gamma=0.97),
}


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env-id", default=None, help="magwarp env id (default: magwarp/PushBox-v0)")
    p.add_argument("--env-kwargs", default=None, help="JSON env options")
    p.add_argument("--device", default=None, help="cpu or cuda[:N] (default: cuda when available)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--out", default=None, help="run folder (default: runs/<env>_sac_her)")
    p.add_argument("--resume", default=None, help="checkpoint file or run folder to continue (its options are reused)")
    p.add_argument("--minutes", type=float, default=None, help="wall-clock training budget of this session")
    p.add_argument("--total-steps", type=float, default=None, help="stop after this many env steps (all worlds)")
    p.add_argument("--stop-after", type=float, default=None,
                   help="stop training once the process has run this many seconds (start-up and compilation included)")
    p.add_argument("--num-envs", type=int, default=None)
    p.add_argument("--buffer-steps", type=int, default=None, help="replay capacity in env steps per env")
    p.add_argument("--batch-size", type=int, default=None)
    p.add_argument("--updates-per-step", type=int, default=None, help="gradient steps per batched env step")
    p.add_argument("--learning-starts", type=int, default=None, help="random-action env steps before learning")
    p.add_argument("--gamma", type=float, default=None)
    p.add_argument("--tau", type=float, default=None)
    p.add_argument("--lr", type=float, default=None)
    p.add_argument("--init-alpha", type=float, default=None, help="initial entropy temperature (auto-tuned after)")
    p.add_argument("--her-ratio", type=float, default=None, help="fraction of sampled goals relabelled (future)")
    p.add_argument("--hidden", default=None, help="hidden layer sizes, comma separated")
    p.add_argument("--policy-delay", type=int, default=None, help="actor update every N critic updates")
    p.add_argument("--log-every", type=float, default=10.0, help="seconds between log lines")
    p.add_argument("--checkpoint-every", type=float, default=60.0, help="seconds between checkpoints")
    p.add_argument("--eval-steps", type=int, default=200,
                   help="batched steps of a final deterministic evaluation on the training env (0: none)")
    p.add_argument("--tensorboard", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--torch-threads", type=int, default=None,
                   help="torch CPU threads (default on a CPU device: 1, fastest for these small networks)")
    p.add_argument("--deterministic", action="store_true")
    return p.parse_args(argv)


def resolve_args(args: argparse.Namespace) -> argparse.Namespace:
    if args.resume:
        saved = load_checkpoint(args.resume, "cpu")["args"]
        for k, v in saved.items():
            if k == "stop_after":  # a limit of the earlier process, not of this one
                continue
            if getattr(args, k, None) is None:
                setattr(args, k, v)
        if args.out is None:
            args.out = args.resume if os.path.isdir(args.resume) else os.path.dirname(args.resume)
    args.env_id = args.env_id or "magwarp/PushBox-v0"
    family = next((k for k in PRESETS if k != "default" and k in args.env_id), "default")
    for k, v in {**PRESETS["default"], **PRESETS[family]}.items():
        if getattr(args, k, None) is None:
            setattr(args, k, v)
    if args.device is None:
        args.device = "cuda" if torch.cuda.is_available() else "cpu"
    args.seed = 0 if args.seed is None else args.seed
    args.out = args.out or os.path.join("runs", args.env_id.split("/")[-1] + "_sac_her")
    if args.minutes is None and args.total_steps is None and args.stop_after is None:
        raise ValueError("give a budget: --minutes, --total-steps and/or --stop-after")
    return args


# ------------------------------------------------------------------------------------------------ replay buffer
class HerReplayBuffer:
    """``[capacity, num_envs]`` rings on the device; future-strategy HER over each env's episode storage.

    Every slot remembers its episode id (a per-env counter); ``ep_end[e, id % (capacity + 1)]`` holds the global
    step of that episode's last transition (a large number while it runs). At most ``capacity`` episodes of one env
    touch the window, so ``capacity + 1`` id slots never alias.
    """

    def __init__(self, capacity: int, num_envs: int, dims: dict[str, int], flag_keys: list[str], device):
        T, N, dev = int(capacity), int(num_envs), device
        self.T, self.N, self.device, self.flag_keys = T, N, dev, list(flag_keys)
        self.data = {k: torch.zeros(T, N, d, device=dev) for k, d in dims.items()}
        self.reward = torch.zeros(T, N, device=dev)
        self.terminated = torch.zeros(T, N, dtype=torch.bool, device=dev)
        self.flags = {k: torch.zeros(T, N, dtype=torch.bool, device=dev) for k in self.flag_keys}
        self.ep_id = torch.zeros(T, N, dtype=torch.int64, device=dev)
        self.cur_id = torch.zeros(N, dtype=torch.int64, device=dev)
        self.ep_end = torch.full((N, T + 1), 2**62, dtype=torch.int64, device=dev)
        self.g = 0  # global step count (host int: no sync)

    @property
    def size(self) -> int:
        return min(self.g, self.T)

    @torch.no_grad()
    def add(self, obs: dict, action, reward, next_obs: dict, terminated, done, info: dict) -> None:
        i = self.g % self.T
        for k in OBS_KEYS:
            self.data[k][i] = obs[k]
            self.data["next_" + k][i] = next_obs[k]
        self.data["action"][i] = action
        self.reward[i] = reward
        self.terminated[i] = terminated
        for k in self.flag_keys:
            self.flags[k][i] = info[k].bool()
        self.ep_id[i] = self.cur_id
        col = (self.cur_id % (self.T + 1))[:, None]
        end = torch.where(done[:, None], torch.full_like(col, self.g), self.ep_end.gather(1, col))
        self.ep_end.scatter_(1, col, end)
        self.cur_id += done.long()
        col = (self.cur_id % (self.T + 1))[:, None]  # a new episode starts: its end is unknown
        end = torch.where(done[:, None], torch.full_like(col, 2**62), self.ep_end.gather(1, col))
        self.ep_end.scatter_(1, col, end)
        self.g += 1

    @torch.no_grad()
    def sample(self, batch: int, her_ratio: float, compute_reward):
        size = self.size
        g0 = self.g - size  # global step of the oldest stored slot
        gt = g0 + torch.randint(size, (batch,), device=self.device)
        e = torch.randint(self.N, (batch,), device=self.device)
        i = gt % self.T
        out = {k: v[i, e] for k, v in self.data.items()}
        reward, terminated = self.reward[i, e], self.terminated[i, e]
        flags = {k: v[i, e] for k, v in self.flags.items()}
        # Future strategy: a later step of the same episode (up to its end, or the newest step while it runs).
        end = self.ep_end[e, self.ep_id[i, e] % (self.T + 1)].clamp(max=self.g - 1)
        span = (end - gt + 1).clamp(min=1)
        fut = gt + (torch.rand(batch, device=self.device) * span).long().clamp(max=span - 1)
        new_goal = self.data["next_achieved_goal"][fut % self.T, e]
        relabel = torch.rand(batch, device=self.device) < her_ratio
        goal = torch.where(relabel[:, None], new_goal, out["desired_goal"])
        out["desired_goal"] = goal
        out["next_desired_goal"] = goal
        new_reward = compute_reward(out["next_achieved_goal"], goal, flags).to(reward.dtype)
        out["reward"] = torch.where(relabel, new_reward, reward)
        out["terminated"] = terminated
        return out


# ------------------------------------------------------------------------------------------------ networks
class Actor(nn.Module):
    def __init__(self, n_obs: int, n_act: int, hidden: list[int]):
        super().__init__()
        self.net = mlp(n_obs, hidden, 2 * n_act, act=nn.ReLU)
        self.n_act = n_act

    def forward(self, x: torch.Tensor, deterministic: bool = False):
        mu, log_std = self.net(x).split(self.n_act, dim=-1)
        log_std = log_std.clamp(-5.0, 2.0)
        if deterministic:
            return torch.tanh(mu), None
        eps = torch.randn_like(mu)
        u = mu + log_std.exp() * eps
        a = torch.tanh(u)
        logp = (-0.5 * eps.square() - log_std - 0.9189385332046727).sum(-1)
        logp = logp - (2 * (0.6931471805599453 - u - F.softplus(-2 * u))).sum(-1)  # tanh correction
        return a, logp

    def mean_net(self) -> nn.Sequential:
        """A copy that outputs only the pre-tanh mean (what the exported policy runs)."""
        net = copy.deepcopy(self.net)
        last = net[-1]
        head = nn.Linear(last.in_features, self.n_act)
        with torch.no_grad():
            head.weight.copy_(last.weight[: self.n_act])
            head.bias.copy_(last.bias[: self.n_act])
        net[-1] = head
        return net


class Critic(nn.Module):
    """Two Q networks (clipped double Q), with layer norm for stability at large batches."""

    def __init__(self, n_obs: int, n_act: int, hidden: list[int]):
        super().__init__()
        self.q1 = mlp(n_obs + n_act, hidden, 1, act=nn.ReLU, layer_norm=True)
        self.q2 = mlp(n_obs + n_act, hidden, 1, act=nn.ReLU, layer_norm=True)

    def forward(self, x, a):
        xa = torch.cat([x, a], -1)
        return self.q1(xa).squeeze(-1), self.q2(xa).squeeze(-1)


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
    N = args.num_envs
    space = base.single_observation_space
    n_obs, n_act = obs_dim(space), int(base.single_action_space.shape[0])
    action_scale = torch.as_tensor(base.single_action_space.high, device=device, dtype=torch.float32)
    hidden = [int(h) for h in str(args.hidden).split(",")]

    actor = Actor(n_obs, n_act, hidden).to(device)
    critic = Critic(n_obs, n_act, hidden).to(device)
    critic_target = copy.deepcopy(critic).requires_grad_(False)
    log_alpha = torch.full((), float(args.init_alpha), device=device).log().requires_grad_(True)
    target_entropy = -float(n_act)
    actor_opt = torch.optim.Adam(actor.parameters(), lr=args.lr)
    critic_opt = torch.optim.Adam(critic.parameters(), lr=args.lr)
    alpha_opt = torch.optim.Adam([log_alpha], lr=args.lr)
    obs_rms = RunningMeanStd(n_obs, device, clip=5.0)
    global_step, updates, wall_before = 0, 0, 0.0
    os.makedirs(args.out, exist_ok=True)
    if args.resume:
        ckpt = load_checkpoint(args.resume, device)
        actor.load_state_dict(ckpt["actor"])
        critic.load_state_dict(ckpt["critic"])
        critic_target.load_state_dict(ckpt["critic_target"])
        with torch.no_grad():
            log_alpha.copy_(ckpt["log_alpha"])
        for opt, key in ((actor_opt, "actor_opt"), (critic_opt, "critic_opt"), (alpha_opt, "alpha_opt")):
            opt.load_state_dict(ckpt[key])
        obs_rms.load_state_dict(ckpt["obs_rms"])
        global_step, updates, wall_before = ckpt["global_step"], ckpt["updates"], ckpt["wall_s"]
        print(f"resumed from {args.resume} at step {global_step:,} ({updates:,} updates)")

    obs, info = env.reset(seed=args.seed)
    # Collision flags the env's compute_reward reads: keep them with every transition (learned from one step, which
    # also compiles the kernels and captures the step graph before the clock starts).
    probe = {k: v.shape for k, v in env.step(torch.zeros(N, n_act, device=device))[4].items()
             if k.endswith("collision") and isinstance(v, torch.Tensor)}
    flag_keys = sorted(probe)
    obs, _ = env.reset(seed=args.seed)
    dims = {}
    for k in OBS_KEYS:
        dims[k] = dims["next_" + k] = int(space[k].shape[0])
    dims["action"] = n_act
    buffer = HerReplayBuffer(args.buffer_steps, N, dims, flag_keys, device)

    def norm(o: dict) -> torch.Tensor:
        return obs_rms.normalize(torch.cat([o[k] for k in OBS_KEYS], -1))

    tracker = SuccessTracker(N, device)
    logger = CsvLogger(args.out, args.tensorboard, resume=bool(args.resume))
    timer = Timer(args.minutes, wall_before, args.stop_after)
    total = None if args.total_steps is None else int(args.total_steps)
    bar = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=total if total else max(int(timer.limit), 1), unit="step" if total else "s",
                   unit_scale=bool(total), desc=f"sac-her {args.env_id.split('/')[-1]}", dynamic_ncols=True,
                   mininterval=1.0)

    def save_all(summary: dict | None = None) -> None:
        state = {"algo": "sac-her", "args": {k: v for k, v in vars(args).items() if k != "resume"},
                 "actor": actor.state_dict(), "critic": critic.state_dict(), "critic_target": critic_target.state_dict(),
                 "log_alpha": log_alpha.detach(), "actor_opt": actor_opt.state_dict(), "critic_opt": critic_opt.state_dict(),
                 "alpha_opt": alpha_opt.state_dict(), "obs_rms": obs_rms.state_dict(), "global_step": global_step,
                 "updates": updates, "wall_s": timer.total}
        save_checkpoint(os.path.join(args.out, "checkpoint.pt"), state)
        save_policy(os.path.join(args.out, "policy.pt"), actor.mean_net(), obs_rms, action_scale, squash="tanh",
                    env_id=args.env_id, metadata={"algo": "sac-her", "env_kwargs": args.env_kwargs,
                                                  "global_step": global_step, "wall_s": timer.total, **(summary or {})})

    online_params, target_params = list(critic.parameters()), list(critic_target.parameters())

    def update(batch: dict) -> dict[str, torch.Tensor]:
        nonlocal updates
        x = norm({k: batch[k] for k in OBS_KEYS})
        x2 = norm({k: batch["next_" + k] for k in OBS_KEYS})
        alpha = log_alpha.exp().detach()
        with torch.no_grad():
            a2, logp2 = actor(x2)
            q1t, q2t = critic_target(x2, a2)
            not_done = (~batch["terminated"]).float()
            target = batch["reward"] + args.gamma * not_done * (torch.min(q1t, q2t) - alpha * logp2)
        q1, q2 = critic(x, batch["action"])
        q_loss = F.mse_loss(q1, target) + F.mse_loss(q2, target)
        critic_opt.zero_grad(set_to_none=True)
        q_loss.backward()
        critic_opt.step()
        out = {"loss_q": q_loss.detach()}
        updates += 1
        if updates % args.policy_delay == 0:
            a, logp = actor(x)
            q = torch.min(*critic(x, a))
            pi_loss = (alpha * logp - q).mean()
            actor_opt.zero_grad(set_to_none=True)
            pi_loss.backward()
            actor_opt.step()
            alpha_loss = -(log_alpha * (logp.detach() + target_entropy)).mean()
            alpha_opt.zero_grad(set_to_none=True)
            alpha_loss.backward()
            alpha_opt.step()
            out["loss_pi"] = pi_loss.detach()
        with torch.no_grad():  # Polyak averaging of the target critic, one fused call
            torch._foreach_lerp_(target_params, online_params, args.tau)
        return out

    last_log = last_ckpt = time.perf_counter()
    steps_at_log, stats, losses = global_step, {"success_rate": float("nan")}, {}
    env_steps = 0  # batched steps of this session
    # A resumed run has trained networks: it acts with them at once and learns as soon as the buffer has a few steps.
    warmup = min(args.learning_starts, 5) if args.resume else args.learning_starts
    while not timer.expired and (total is None or global_step < total):
        with torch.no_grad():
            if env_steps < warmup and not args.resume:
                action = torch.rand(N, n_act, device=device) * 2 - 1
            else:
                action, _ = actor(norm(obs))
            next_obs, reward, terminated, truncated, info = env.step(action * action_scale)
            done = terminated | truncated
            buffer.add(obs, action, reward, info["final_obs"], terminated, done, info)
            obs_rms.update(flatten_obs(obs))
            tracker.update(reward, terminated, truncated, info)
            obs = next_obs
        env_steps += 1
        global_step += N
        if env_steps >= warmup:
            for _ in range(args.updates_per_step):
                losses = update(buffer.sample(args.batch_size, args.her_ratio, base.compute_reward))

        now = time.perf_counter()
        final = timer.expired or (total is not None and global_step >= total)
        if now - last_log >= args.log_every or final:
            stats = tracker.pop()
            sps = (global_step - steps_at_log) / max(now - last_log, 1e-9)
            row = {"global_step": global_step, "updates": updates, "wall_s": round(timer.total, 2), "sps": round(sps),
                   **stats, "alpha": float(log_alpha.detach().exp()), **{k: float(v) for k, v in losses.items()}}
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
        ev = evaluate(env, lambda o: actor(norm(o), deterministic=True)[0] * action_scale, args.eval_steps,
                      seed=args.seed + 10_000)
        summary.update({f"eval_{k}": v for k, v in ev.items()})
        print(f"deterministic evaluation ({args.eval_steps} steps x {N} envs): success {ev['success_rate']:.4f}, "
              f"collisions/episode {ev['collisions_per_episode']:.4f}, {ev['episodes']:.0f} episodes")
    save_all(summary)
    logger.close()
    plot_curve(logger.path, os.path.join(args.out, "curve.png"), f"SAC+HER {args.env_id} ({args.device})")
    print(f"saved {args.out}/policy.pt, checkpoint.pt, progress.csv, curve.png; "
          f"final success {stats['success_rate']:.3f}")
    env.close()
    return summary


def main(argv=None) -> int:
    train(parse_args(argv))
    return 0


if __name__ == "__main__":
    sys.exit(main())
