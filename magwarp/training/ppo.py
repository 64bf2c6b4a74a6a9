"""PPO on a batched magwarp env, torch-native and CleanRL-style (one file, read top to bottom).

The whole rollout stays on the env's device: thousands of worlds step together, observations are normalised with
running statistics, and episodes follow Gymnasium: ``terminated`` ends the return, ``truncated`` bootstraps from the
value of the episode's last observation (``info["final_obs"]``, since the env resets in the same step).

    python -m magwarp.training.ppo --env-id magwarp/TrajectoryPlanningB0-v0 --device cuda --minutes 15 --out runs/b0_ppo
    python -m magwarp.training.ppo --resume runs/b0_ppo --minutes 5          # continue the same run
    python -m magwarp.training.ppo --init-policy pretrained:b0_ppo ...      # fine-tune a policy file (new critic)
    magwarp train magwarp/TrajectoryPlanningB0-v0 --algo ppo --minutes 15     # the same, through the CLI
    torchrun --standalone --nproc-per-node 4 -m magwarp.training.ppo --env-id ...   # 4 GPUs (--num-envs per GPU)

Speed levers (``--help``): on CUDA every minibatch update is a replayed CUDA graph (``--cuda-graph``, on by default);
``--squash tanh`` samples a tanh-squashed Gaussian (actions never pile up at the bounds); ``--compile on``
(torch.compile) and ``--amp bf16`` are options; ``--profile`` shows where an iteration's time goes. The trajectory
planning preset (16,384 worlds x 16 steps, 8 minibatches) reached B0's target in about a minute on one H100
(``benchmarks/time_to_target.py``).

Writes under ``--out``: ``progress.csv`` (+ ``tb/`` with ``--tensorboard``), ``curve.png``, ``checkpoint.pt``
(resume), ``policy.pt`` (TorchScript; ``magwarp eval`` and ``magwarp export`` load it: see
:mod:`magwarp.training.policy`) and ``run.json`` (summary, time to target: :mod:`magwarp.training.loop`).
Under torchrun (:mod:`magwarp.training.distributed`) gradients are averaged over the ranks and rank 0 writes the files.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import torch
import torch.nn.functional as F
from torch import nn

from magwarp._streams import gc_paused
from magwarp.training import distributed as dist
from magwarp.training.common import (RunningMeanStd, autocast, configure_adam, flatten_obs, load_checkpoint,
                                     save_checkpoint, set_lr)
from magwarp.training.loop import Session, add_run_args, entry_point, open_env, resolve_run_args, run_training
from magwarp.training.policy import mlp, save_policy

DEFAULT_ENV = "magwarp/TrajectoryPlanningB0-v0"

# Hyper-parameters per task family (any option given on the command line wins). Tuned for thousands of worlds on
# one GPU; "default" is used for env ids that match no family.
PRESETS = {
    "default": dict(num_envs=4096, num_steps=32, num_minibatches=4, update_epochs=5, lr=3e-4, gamma=0.99,
                    gae_lambda=0.95, ent_coef=0.0, hidden="256,256,128", init_log_std=-0.5, desired_kl=0.01),
    # 16,384 worlds x 16 steps in 8 minibatches: on one H100, B0 ran 1.3-1.6 M env-steps/s (4096 x 32 in 4: 0.4 M,
    # 0.5 M with graphed updates) and reached 99% success with < 2.14 collisions per 1000 goals after 68 s instead of
    # not within 90 s (benchmarks/time_to_target.py)
    "TrajectoryPlanning": dict(num_envs=16384, num_steps=16, num_minibatches=8, gamma=0.99, hidden="256,256,128"),
    # cooperative pushing as a residual on its scripted baseline (magwarp.envs.coop_push_residual): the actor's last
    # layer starts at zero (the baseline's 73% success), a fresh critic learns alone first, and the noise (std 0.2 of
    # the correction's range: 1 m/s^2; measured on the CPU: 70% success at that noise, 67% at half of it, 41%
    # at twice, 74% without; 128 episodes each) and KL-capped steps keep the start's success while it learns
    "CoopPushResidual": dict(num_envs=4096, num_steps=32, num_minibatches=4, gamma=0.99, hidden="256,256",
                             init_log_std=-1.6, lr=1e-4, desired_kl=0.005, actor_init="zero", critic_warmup=10),
    "Push": dict(num_envs=4096, num_steps=25, gamma=0.97, hidden="256,256,128"),
    # swarms train on the flat agent view: num_envs worlds x num_movers agents (64 x 64 = 4096 by default). The
    # residual on the planner (magwarp.swarm.residual; before "Swarm", which its id also contains) starts as
    # CoopPushResidual does: a zero actor (the planner's numbers), a critic trained alone first, noise of std 0.2 of
    # the correction's range (1 m/s^2 at residual_scale 0.5) and small, KL-capped steps
    "SwarmResidual": dict(num_envs=64, num_steps=32, gamma=0.98, hidden="256,256", init_log_std=-1.6, lr=1e-4,
                          desired_kl=0.005, actor_init="zero", critic_warmup=10),
    "Swarm": dict(num_envs=64, num_steps=32, gamma=0.98, hidden="256,256"),
    # levitation (1 kHz steps, 500-step episodes): gamma 0.99 looks 0.1 s ahead (the PD's transient takes ~50 ms);
    # a small initial std, because a free 6-DoF mover 4 mm above the tiles falls or tips within ~25 ms of a bad
    # wrench. The residual env starts at the PD baseline: a smaller std still (exploration noise costs copper
    # energy) and small, KL-capped steps. Not yet shown to beat the PD: on the CPU (256-512 worlds), ~1 M steps
    # ended 2.4% above the PD's energy and 0.6% above its position RMS with these settings (3% and 1% with lr
    # 1.5e-4, KL 0.01), and 2.4 M steps drifted further (+10%, +9%, a 0.65 mm steady offset; lr 2e-5, 2 epochs,
    # 1024 worlds: +8%, +4% after 1.7 M): the drift is systematic: the residual learns a steady upward force (0.8 mm
    # above the setpoint after 0.6 M steps on the CPU) although a constant one lowers the return; with --gae-lambda
    # 1.0 (Monte-Carlo advantages, no critic slope in them) it stayed near zero (paper.py's lev_residual_soft);
    # benchmarks/levitation_policy.py measures a run
    "LevitationResidual": dict(num_envs=4096, num_steps=32, num_minibatches=4, gamma=0.99, hidden="256,256",
                               init_log_std=-3.0, lr=5e-5, desired_kl=0.005),
    "Levitation": dict(num_envs=4096, num_steps=32, num_minibatches=4, gamma=0.99, hidden="256,256",
                       init_log_std=-2.0),
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
    p.add_argument("--init-policy", default=None,
                   help="warm start: the actor and observation normaliser of a policy file (e.g. pretrained:b0_ppo, "
                   "to fine-tune it under domain randomisation); same --hidden, --activation, --squash and action "
                   "scale; the critic starts fresh")
    p.add_argument("--critic-warmup", type=int, default=None,
                   help="the first N iterations train the critic only (the actor and its std stay put, the adaptive "
                   "learning rate waits): with --init-policy, a fresh critic's advantages would first undo the actor")
    p.add_argument("--activation", choices=tuple(ACTIVATIONS), default=None,
                   help="hidden activation (default elu); relu or tanh keep the policy inside the operator list of "
                   "Beckhoff's real-time MLP runtime (magwarp export --target twincat-mlp refuses Elu)")
    p.add_argument("--init-log-std", type=float, default=None)
    p.add_argument("--actor-init", choices=("orthogonal", "zero"), default=None,
                   help="the actor's last layer: orthogonal with gain 0.01 (default), or zero (a residual env's policy "
                   "then starts exactly at the baseline)")
    p.add_argument("--no-norm-reward", action="store_true", help="do not scale rewards by the return's running std")
    p.add_argument("--squash", choices=("clip", "tanh"), default=None,
                   help="how Gaussian samples become actions: clip to [-1, 1], or tanh (a squashed Gaussian, its "
                        "log-probability corrected: actions do not pile up at the bounds)")
    p.add_argument("--cuda-graph", choices=("auto", "on", "off"), default=None,
                   help="replay each minibatch update as a captured CUDA graph (auto: on CUDA, off under torchrun)")
    p.add_argument("--compile", choices=("off", "on"), default=None,
                   help="torch.compile the networks' update step and the rollout's policy step (compiles count "
                        "in the run's time)")
    p.add_argument("--amp", choices=("off", "bf16"), default=None,
                   help="bf16 autocast for the networks' forward passes (CUDA)")
    return p.parse_args(argv)


def resolve_args(args: argparse.Namespace) -> argparse.Namespace:
    """Fill unset options: from the checkpoint when resuming, then the task preset, then the defaults."""
    args = resolve_run_args(args, PRESETS, DEFAULT_ENV, "ppo")
    for name, default in (("squash", "clip"), ("cuda_graph", "auto"), ("compile", "off"), ("amp", "off"),
                          ("activation", "elu"), ("critic_warmup", 0), ("actor_init", "orthogonal")):
        if getattr(args, name, None) is None:  # checkpoints of earlier versions lack the option
            setattr(args, name, default)
    if int(args.critic_warmup) < 0:
        raise ValueError(f"--critic-warmup must be >= 0 iterations, got {args.critic_warmup!r}")
    for name in ("num_envs", "num_steps", "num_minibatches", "update_epochs"):
        if int(getattr(args, name)) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be a positive integer, got {getattr(args, name)!r}")
    return args


_LOG2 = math.log(2.0)
#: ``--activation``: the hidden layers' nonlinearity
ACTIVATIONS = {"elu": nn.ELU, "relu": nn.ReLU, "tanh": nn.Tanh}
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def squashed_log_prob(mean: torch.Tensor, log_std: torch.Tensor, u: torch.Tensor, squash: str) -> torch.Tensor:
    """Log-density of the action a Gaussian sample ``u`` gives, summed over the action dimensions: for ``clip``, of
    ``u`` itself (PPO's usual ratio of Gaussian densities); for ``tanh``, of ``a = tanh(u)`` (change of variables:
    ``log N(u) - sum log(1 - tanh(u)^2)``, the correction written stably as ``2 (log 2 - u - softplus(-2 u))``)."""
    z = (u - mean) * torch.exp(-log_std)
    logp = (-0.5 * z.square() - log_std - _LOG_SQRT_2PI).sum(-1)
    if squash == "tanh":
        logp = logp - (2.0 * (_LOG2 - u - F.softplus(-2.0 * u))).sum(-1)
    return logp


class Agent(nn.Module):
    """Actor (Gaussian mean, state-independent log std) and critic. ``squash``: how a sample ``u`` becomes an action
    in [-1, 1] (clip, or tanh); ``amp``: bf16 autocast of the networks (outputs in float32); ``actor_init``: the
    actor's last layer, orthogonal (gain 0.01) or zero (a zero mean action until the first update)."""

    def __init__(self, n_obs: int, n_act: int, hidden: list[int], init_log_std: float, squash: str = "clip",
                 amp: str = "off", activation: str = "elu", actor_init: str = "orthogonal"):
        super().__init__()
        if actor_init not in ("orthogonal", "zero"):
            raise ValueError(f"actor_init must be 'orthogonal' or 'zero', got {actor_init!r}")
        if squash not in ("clip", "tanh"):
            raise ValueError(f"squash must be 'clip' or 'tanh', got {squash!r}")
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {', '.join(ACTIVATIONS)}, got {activation!r}")
        act = ACTIVATIONS[activation]
        self.actor_mean = mlp(n_obs, hidden, n_act, act)
        self.critic = mlp(n_obs, hidden, 1, act)
        self.log_std = nn.Parameter(torch.full((n_act,), float(init_log_std)))
        if actor_init == "zero":  # the mean action is 0 until the first update (a residual env's baseline)
            nn.init.zeros_(self.actor_mean[-1].weight)
        else:
            nn.init.orthogonal_(self.actor_mean[-1].weight, 0.01)
        nn.init.zeros_(self.actor_mean[-1].bias)
        self.squash, self.amp = squash, amp

    def _net(self, net: nn.Module, x: torch.Tensor) -> torch.Tensor:
        with autocast(x.device, self.amp):
            return net(x).float()

    def value(self, x: torch.Tensor) -> torch.Tensor:
        return self._net(self.critic, x).squeeze(-1)

    def mean_std(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The Gaussian's mean and log std (clamped to [-5, 1]) for observations ``x``."""
        mean = self._net(self.actor_mean, x)
        return mean, self.log_std.clamp(-5.0, 1.0).expand_as(mean)

    def dist(self, x: torch.Tensor) -> torch.distributions.Normal:
        mean, log_std = self.mean_std(x)
        return torch.distributions.Normal(mean, log_std.exp())

    def to_action(self, u: torch.Tensor) -> torch.Tensor:
        """A sample (or the mean) -> an action in [-1, 1]."""
        return torch.tanh(u) if self.squash == "tanh" else u.clamp(-1.0, 1.0)

    def rollout_step(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One rollout step's policy work: (sample u, its log-probability, the value of ``x``)."""
        mean, log_std = self.mean_std(x)
        u = mean + log_std.exp() * torch.randn_like(mean)
        return u, squashed_log_prob(mean, log_std, u, self.squash), self.value(x)


class PpoUpdate:
    """The PPO update of one rollout: ``update_epochs`` passes over the batch in ``num_minibatches`` random
    minibatches, each a clipped-loss gradient step (gradient clipping, Adam).

    The rollout is staged into fixed buffers and each step picks its minibatch (a row of precomputed indices)
    through a device counter, so the same step runs eagerly or, on CUDA (``--cuda-graph``), as one captured graph
    replayed once per minibatch: the first few steps of the first update run eagerly (warm-up: Adam's state, cuBLAS
    workspaces), then the step is captured and replayed. ``--compile`` compiles the loss (forward and backward)."""

    def __init__(self, agent: Agent, optimizer: torch.optim.Optimizer, args: argparse.Namespace, device,
                 n_obs: int, n_act: int, num_envs: int | None = None):
        self.agent, self.optimizer, self.args, self.device = agent, optimizer, args, torch.device(device)
        # the rollout's sub-envs: the worlds, or every mover of every world (a swarm's flat agent view)
        batch = int(args.num_envs if num_envs is None else num_envs) * args.num_steps
        self.mb = batch // args.num_minibatches
        if self.mb < 1:
            raise ValueError(f"--num-minibatches {args.num_minibatches} exceeds the batch of {batch} samples")
        self.steps = args.update_epochs * args.num_minibatches
        self.graphed = args.cuda_graph == "on" or (args.cuda_graph == "auto" and self.device.type == "cuda"
                                                   and dist.world_size() == 1)
        if self.graphed and self.device.type != "cuda":
            raise ValueError(f"--cuda-graph on needs a CUDA device, got {self.device}")
        if self.graphed and dist.world_size() > 1:
            raise ValueError("--cuda-graph on is not supported under torchrun (gradients are all-reduced between "
                             "updates): use --cuda-graph auto or off")
        configure_adam([optimizer], self.graphed, self.device)
        dev = self.device
        self.stage = {"obs": torch.zeros(batch, n_obs, device=dev), "act": torch.zeros(batch, n_act, device=dev),
                      **{k: torch.zeros(batch, device=dev) for k in ("logp", "adv", "ret", "val")}}
        self.idx = torch.zeros(self.steps, self.mb, dtype=torch.int64, device=dev)
        self.kl = torch.zeros(self.steps, device=dev)
        self.cursor = torch.zeros(1, dtype=torch.int64, device=dev)
        self.loss = torch.compile(ppo_loss) if args.compile == "on" else ppo_loss
        self._graph = None  # (graph, its static outputs) once captured
        # --critic-warmup: the actor's gradients times this gate (0 while the critic warms up); none without it
        self.actor_gate = torch.ones((), device=dev) if getattr(args, "critic_warmup", 0) else None
        self._actor_params = [*agent.actor_mean.parameters(), agent.log_std]
        self._actor_on = True

    def gate_actor(self, on: bool) -> None:
        """Train the actor (``on``) or the critic only, from the next update (device fills: no recapture). When the
        actor starts, its Adam moments and step count start from zero: moments kept at zero through the warm-up
        under an advanced step count would lose Adam's bias correction, and the first updates would move every
        weight by several learning rates (measured: a fine-tuned B0 policy fell from 90 % to 8 % success)."""
        if self.actor_gate is None:
            raise ValueError("gate_actor needs --critic-warmup")
        if on and not self._actor_on:
            for p in self._actor_params:
                for value in self.optimizer.state.get(p, {}).values():
                    if isinstance(value, torch.Tensor):
                        value.zero_()
        self._actor_on = bool(on)
        self.actor_gate.fill_(1.0 if on else 0.0)

    def reconfigure(self) -> None:
        """After loading an optimizer state: capturable (graphed) or plain, as this run trains."""
        configure_adam([self.optimizer], self.graphed, self.device)

    def set_lr(self, lr: float) -> None:
        set_lr([self.optimizer], lr)

    def _step(self) -> tuple[torch.Tensor, torch.Tensor]:
        idx = self.idx.index_select(0, self.cursor)[0]
        mb = {k: v.index_select(0, idx) for k, v in self.stage.items()}
        loss, kl, pg_loss, v_loss = self.loss(self.agent, self.args, mb["obs"], mb["act"], mb["logp"], mb["adv"],
                                              mb["ret"], mb["val"])
        self.optimizer.zero_grad(set_to_none=False)  # in place: a captured graph keeps its gradient buffers
        loss.backward()
        if self.actor_gate is not None:
            torch._foreach_mul_([p.grad for p in self._actor_params], self.actor_gate)
        dist.average_gradients(self.agent.parameters())  # torchrun: the mean gradient of all ranks' minibatches
        nn.utils.clip_grad_norm_(self.agent.parameters(), self.args.max_grad_norm)
        self.optimizer.step()
        self.kl.index_copy_(0, self.cursor, kl.detach().reshape(1))
        self.cursor.add_(1)
        return pg_loss.detach(), v_loss.detach()

    def _capture(self, warmup: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``warmup`` eager steps on a side stream (real updates), then the step captured (not run)."""
        side = torch.cuda.Stream(self.device)
        side.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(side):
            for _ in range(warmup):
                out = self._step()
        torch.cuda.current_stream(self.device).wait_stream(side)
        self.optimizer.zero_grad(set_to_none=True)  # the capture allocates the gradients from the graph's pool
        graph = torch.cuda.CUDAGraph()
        with gc_paused(), torch.cuda.graph(graph):
            static = self._step()
        self._graph = (graph, static)
        return out

    @torch.no_grad()
    def _stage(self, data: dict[str, torch.Tensor]) -> None:
        for k, v in data.items():
            self.stage[k].copy_(v.reshape(self.stage[k].shape))
        n = self.stage["obs"].shape[0]
        self.idx.copy_(torch.stack([torch.randperm(n, device=self.device)[:self.args.num_minibatches * self.mb]
                                    for _ in range(self.args.update_epochs)]).reshape(self.steps, self.mb))
        self.cursor.zero_()

    def run(self, data: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """All minibatch steps on one rollout (``obs, act, logp, adv, ret, val``); returns the mean approximate KL
        and the last policy and value losses (device tensors)."""
        self._stage(data)
        done = 0
        if self.graphed and self._graph is None:
            done = min(3, self.steps)
            out = self._capture(done)
        for _ in range(self.steps - done):
            if self._graph is not None:
                self._graph[0].replay()
                out = self._graph[1]
            else:
                out = self._step()
        return self.kl.mean(), *out


def train(args: argparse.Namespace) -> dict:
    """PPO: train until the budget is spent; returns the summary (final success rate, env steps, wall seconds,
    time to target). Under torchrun, every rank calls this (see :mod:`magwarp.training.distributed`)."""
    return run_training(args, resolve_args, _train)


#: how many observations the normaliser loaded by ``--init-policy`` counts as (its running statistics then move slowly
#: towards the new env's: a few hundred iterations of 16,384 worlds)
INIT_POLICY_COUNT = 1e6


def init_from_policy(path: str, agent: Agent, obs_rms: RunningMeanStd, action_scale: torch.Tensor, squash: str) -> None:
    """Load a policy file's actor network and observation normaliser into ``agent`` and ``obs_rms`` (a warm start;
    the critic and the log std stay as built). Refused, naming the difference, unless the file's network has the
    same layers, activation, squash, observation size and action scale."""
    from magwarp.training.policy import load_policy
    from magwarp.training.pretrained import resolve_policy

    flat = load_policy(resolve_policy(path)).flat
    theirs, ours = flat.net.state_dict(), agent.actor_mean.state_dict()
    shapes = {k: tuple(v.shape) for k, v in theirs.items()}
    want = {k: tuple(v.shape) for k, v in ours.items()}
    acts = [getattr(m, "original_name", type(m).__name__) for m in flat.net.children()]
    own_acts = [type(m).__name__ for m in agent.actor_mean.children()]
    problems = []
    if shapes != want:
        problems.append(f"its network's layers {sorted(set(shapes.values()))} are not this run's "
                        f"{sorted(set(want.values()))} (--hidden)")
    elif acts != own_acts:
        problems.append(f"its layers {acts} are not this run's {own_acts} (--activation)")
    if bool(flat.use_tanh) != (squash == "tanh"):
        problems.append(f"it squashes with {'tanh' if flat.use_tanh else 'clip'}, this run with {squash} (--squash)")
    if flat.obs_mean.numel() != obs_rms.mean.numel():
        problems.append(f"it takes {flat.obs_mean.numel()} observations, this env gives {obs_rms.mean.numel()}")
    elif not torch.allclose(flat.action_scale.cpu(), action_scale.detach().cpu().to(torch.float32)):
        problems.append(f"its action scale {flat.action_scale.tolist()} is not this env's {action_scale.tolist()}")
    if problems:
        raise ValueError(f"--init-policy {path}: " + "; ".join(problems))
    agent.actor_mean.load_state_dict(theirs)
    dev = obs_rms.mean.device
    obs_rms.mean.copy_(flat.obs_mean.to(dev, torch.float64))
    obs_rms.var.copy_((flat.obs_std.to(dev, torch.float64).square() - 1e-8).clamp(min=0.0))
    obs_rms.count.fill_(INIT_POLICY_COUNT)


def _train(args: argparse.Namespace) -> dict:
    main_rank, world = dist.is_main(), dist.world_size()
    seed, env, base, n_obs, n_act, action_scale = open_env(args)
    device = base.device  # the env's device, with its index (cuda -> cuda:0)
    N, T = env.num_envs, args.num_steps  # sub-envs: the worlds, or every mover of every world (swarms' agent view)
    hidden = [int(h) for h in str(args.hidden).split(",")]

    agent = Agent(n_obs, n_act, hidden, args.init_log_std, args.squash, args.amp, args.activation,
                  args.actor_init).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.lr, eps=1e-5)
    update = PpoUpdate(agent, optimizer, args, device, n_obs, n_act, num_envs=N)
    obs_rms = RunningMeanStd(n_obs, device, clip=10.0)
    ret_rms = RunningMeanStd(1, device)
    global_step, iteration, wall_before, lr, target_state = 0, 0, 0.0, args.lr, None
    if args.resume:
        ckpt = load_checkpoint(args.resume, device)
        agent.load_state_dict(ckpt["agent"])
        optimizer.load_state_dict(ckpt["optimizer"])
        update.reconfigure()  # the saved run may have been eager, or graphed
        obs_rms.load_state_dict(ckpt["obs_rms"])
        ret_rms.load_state_dict(ckpt["ret_rms"])
        global_step, iteration, wall_before, lr = ckpt["global_step"], ckpt["iteration"], ckpt["wall_s"], ckpt["lr"]
        target_state = ckpt.get("target")
        if main_rank:
            print(f"resumed from {args.resume} at step {global_step:,} (iteration {iteration})")
    elif getattr(args, "init_policy", None):
        init_from_policy(args.init_policy, agent, obs_rms, action_scale, args.squash)
        if main_rank:
            print(f"actor and observation normaliser from {args.init_policy}")
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
    tracker, phase = session.tracker, session.phases
    policy_step = torch.compile(agent.rollout_step) if args.compile == "on" else agent.rollout_step
    # One step before the clock starts: kernels compile and the step graph is captured (minutes on a cold cache).
    env.reset(seed=seed)
    env.step(torch.zeros(N, n_act, device=device))

    def act(o):  # the deterministic policy (what policy.pt runs)
        return agent.to_action(agent.actor_mean(obs_rms.normalize(flatten_obs(o)))) * action_scale

    def save_all(summary: dict | None = None) -> None:
        dist.check_in_sync([*agent.parameters(), *obs_rms.buffers()])  # torchrun: every rank holds rank 0's
        if not main_rank:
            return
        state = {"algo": "ppo", "args": {k: v for k, v in vars(args).items() if k != "resume"},
                 "agent": agent.state_dict(), "optimizer": optimizer.state_dict(), "obs_rms": obs_rms.state_dict(),
                 "ret_rms": ret_rms.state_dict(), "global_step": global_step, "iteration": iteration,
                 "wall_s": session.timer.total, "lr": lr, "target": session.target.state()}
        save_checkpoint(os.path.join(args.out, "checkpoint.pt"), state)
        save_policy(os.path.join(args.out, "policy.pt"), agent.actor_mean, obs_rms, action_scale, squash=args.squash,
                    env_id=args.env_id, metadata={"algo": "ppo", "env_kwargs": args.env_kwargs,
                                                  "eval_env_kwargs": args.eval_env_kwargs,
                                                  "global_step": global_step, "wall_s": session.timer.total,
                                                  **(summary or {})})
        standalone = getattr(base, "write_standalone_policy", None)  # a residual env's policy on its base env
        if standalone is not None:
            standalone(os.path.join(args.out, "policy.pt"), os.path.join(args.out, base.STANDALONE_POLICY))

    obs, _ = env.reset(seed=seed)
    raw = flatten_obs(obs)
    obs_rms.update(raw)
    next_obs = obs_rms.normalize(raw)
    stop = session.start(wall_before, global_step)
    while not stop:
        # ---------------------------------------------------------------- rollout (no host sync)
        with torch.no_grad():
            for t in range(T):
                with phase("policy"):
                    b_obs[t] = next_obs
                    u, logp, value = policy_step(next_obs)
                    b_act[t], b_logp[t], b_val[t] = u, logp, value
                    action = agent.to_action(u) * action_scale
                with phase("env"):
                    obs, reward, terminated, truncated, info = env.step(action)
                with phase("policy"):
                    tracker.update(reward, terminated, truncated, info)
                    done = terminated | truncated
                    raw = flatten_obs(obs)
                    obs_rms.update(raw)
                    next_obs = obs_rms.normalize(raw)
                    # Truncation: bootstrap from the value of the finished episode's last observation.
                    final_v = agent.value(obs_rms.normalize(flatten_obs(info["final_obs"])))
                    reward = reward + args.gamma * final_v * (truncated & ~terminated) * (
                        ret_rms.var.sqrt().float() if not args.no_norm_reward else 1)
                    if not args.no_norm_reward:  # scale by the running std of the discounted return
                        disc_return.mul_(args.gamma).add_(reward)
                        ret_rms.update(disc_return[:, None])
                        disc_return.masked_fill_(done, 0.0)
                        reward = reward / torch.sqrt(ret_rms.var + 1e-8).float()
                    b_rew[t] = reward
                    b_done[t] = done.float()
            with phase("policy"):
                # GAE over the rollout (done at t: the episode ended at step t, its bootstrap is in the reward).
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
        with phase("update"):
            warming = iteration <= args.critic_warmup
            if update.actor_gate is not None:
                update.gate_actor(not warming)
            kl, pg_loss, v_loss = update.run({"obs": b_obs, "act": b_act, "logp": b_logp, "adv": adv, "ret": ret,
                                              "val": b_val})
            if args.desired_kl > 0 and not warming:  # adaptive learning rate (one host sync per iteration)
                kl_mean = float(dist.all_reduce_sum_(kl.clone()) / world)
                if kl_mean > 2.0 * args.desired_kl:
                    lr = max(lr / 1.5, 1e-6)
                elif kl_mean < 0.5 * args.desired_kl:
                    lr = min(lr * 1.5, 1e-2)
                update.set_lr(lr)

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
    """The clipped PPO loss of one minibatch: (loss, approximate KL, policy loss, value loss). ``act`` holds the
    Gaussian samples (before clipping or tanh)."""
    mean, log_std = agent.mean_std(obs)
    logp = squashed_log_prob(mean, log_std, act, agent.squash)
    log_ratio = logp - old_logp
    ratio = log_ratio.exp()
    with torch.no_grad():
        kl = ((ratio - 1) - log_ratio).mean()
    a = (adv - adv.mean()) / (adv.std() + 1e-8)
    pg_loss = torch.max(-a * ratio, -a * ratio.clamp(1 - args.clip_coef, 1 + args.clip_coef)).mean()
    v = agent.value(obs)
    v_clipped = old_val + (v - old_val).clamp(-args.clip_coef, args.clip_coef)
    v_loss = 0.5 * torch.max((v - ret).square(), (v_clipped - ret).square()).mean()
    entropy = (log_std + 0.5 + _LOG_SQRT_2PI).sum(-1).mean()  # the Gaussian's (before the squash)
    return pg_loss + args.vf_coef * v_loss - args.ent_coef * entropy, kl, pg_loss, v_loss


main = entry_point(parse_args, train)  # main(argv) -> 0, what `python -m` and torchrun run


if __name__ == "__main__":
    sys.exit(main())
