"""SAC + hindsight experience replay (HER) on a batched magwarp env, torch-native and CleanRL-style (one file, its
networks in :mod:`magwarp.training.sac_networks`).

The replay buffer lives on the env's device as ``[time, env]`` rings. HER uses the *future* strategy over the episode
storage: a sampled transition of env ``e`` at time ``t`` gets, with probability ``--her-ratio``, the goal achieved at a
uniformly drawn later step of the same episode, and its reward is recomputed in one batched call of the env's
``compute_reward(achieved_goal, desired_goal, info)`` (collision flags stored with each transition stay in ``info``).
Episode ends are tracked per env without scanning the buffer, so sampling is O(batch). ``--demo-episodes`` and
``--demo-share`` mix the env's scripted baseline into the collection (:mod:`magwarp.training.demos`), for tasks whose
success random exploration never shows (CoopPush).

``--overlap`` (auto: on for one CUDA device) runs an iteration's env step and its updates at once, on two CUDA streams
(:mod:`magwarp.training.streams`): while the env steps the actions of iteration ``t``, the learner relabels and trains
on the steps up to ``t - 1``, the usual one-step-stale schedule of asynchronous off-policy learners. The action of
step ``t`` comes from the actor after the updates of iteration ``t - 1``, before those of ``t``; the buffer's step
``t`` is written before any sample may read it (the sample is bounded by what is committed, future goals included).
No host synchronisation in an iteration (the log, evaluation and checkpoint synchronise when due; ``--profile`` once
per iteration). With ``--overlap off`` (and on the CPU) the updates follow the env step and sample it too, as before.

    python -m magwarp.training.sac_her --env-id magwarp/PushBox-v0 --device cuda --minutes 15 --out runs/pushbox_sac
    python -m magwarp.training.sac_her --resume runs/pushbox_sac --minutes 5
    magwarp train magwarp/PushBox-v0 --algo sac-her --minutes 15
    torchrun --standalone --nproc-per-node 4 -m magwarp.training.sac_her --env-id ...   # 4 GPUs

Writes under ``--out``: ``progress.csv`` (+ ``tb/``), ``curve.png``, ``checkpoint.pt`` (networks, optimisers and
normaliser; the replay buffer is not saved: a resumed run refills it), ``policy.pt`` (TorchScript, see
:mod:`magwarp.training.policy`) and ``run.json`` (summary, time to target: :mod:`magwarp.training.loop`).
Under torchrun (:mod:`magwarp.training.distributed`) every rank keeps its own replay buffer and the gradients of
every update are averaged over the ranks (updates then run eagerly: ``--cuda-graph auto`` is off); rank 0 writes
the files.
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import sys
import time

import torch

from magwarp._streams import gc_paused
from magwarp.training import distributed as dist
from magwarp.training.common import (OBS_KEYS, PROCESS_START, RunningMeanStd, configure_adam, flatten_obs,
                                     load_checkpoint, save_checkpoint, set_lr)
from magwarp.training.demos import ScriptedDemos
from magwarp.training.loop import Session, add_run_args, entry_point, open_env, resolve_run_args, run_training
from magwarp.training.policy import save_policy
from magwarp.training.sac_networks import (CRITIC_IMPLS, Actor, convert_critic_optimizer, convert_critic_state,
                                           critic_layout, make_critic, q_min, q_regression_loss)
from magwarp.training.streams import StreamPair

DEFAULT_ENV = "magwarp/PushBox-v0"

# Hyper-parameters per task family (any option given on the command line wins), for one GPU. The paper's runs
# (MagBotSim's docs/parameters) used SB3's SAC with 50 envs, batch 128 and one gradient step per env step (a replay
# ratio of 128 sampled transitions per collected one), lr 1e-3 decaying linearly to 0, gamma 0.95. Here 4096 envs
# collect at once (a mujoco-warp step costs little more than at 1024: 173 vs 132 ms for Push-Box on an H200) and
# ``updates_per_step`` minibatches of ``batch_size`` sample each transition 64 times (64 x 4096 / 4096); on CUDA
# each update is one replayed CUDA graph. Its kernels (benchmarks/sac_update.py on one H100, batch 4096): 1.30 ms per
# update with fused Adam and the two critic MLPs (the defaults), 2.44 ms before (foreach Adam), 1.43 ms with the
# ensemble critic (its batched matmuls are slower than two plain ones at this size), 0.85 ms with --compile on (whose
# first call takes 20 s).
PRESETS = {
    "default": dict(num_envs=4096, buffer_steps=1000, batch_size=4096, updates_per_step=64, learning_starts=10,
                    gamma=0.95, tau=0.01, lr=5e-4, lr_schedule="linear", init_alpha=0.1, her_ratio=0.8,
                    hidden="256,256,256", policy_delay=1, demo_episodes=0, demo_share=0.0,
                    demo_bc=0.0, critic_impl="pair", adam="fused", amp="off", compile="off"),
    "TrajectoryPlanning": dict(gamma=0.99, her_ratio=0.5),
}


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_args(p, DEFAULT_ENV, "sac_her")
    p.add_argument("--buffer-steps", type=int, default=None, help="replay capacity in env steps per env")
    p.add_argument("--batch-size", type=int, default=None)
    p.add_argument("--updates-per-step", type=int, default=None, help="gradient steps per batched env step")
    p.add_argument("--learning-starts", type=int, default=None, help="random-action env steps before learning")
    p.add_argument("--gamma", type=float, default=None)
    p.add_argument("--tau", type=float, default=None)
    p.add_argument("--lr", type=float, default=None, help="initial learning rate of all three optimisers")
    p.add_argument("--lr-schedule", choices=("linear", "constant"), default=None,
                   help="linear: decay to 0 over the budget (--total-steps, else --minutes), as the paper's runs")
    p.add_argument("--init-alpha", type=float, default=None, help="initial entropy temperature (auto-tuned after)")
    p.add_argument("--her-ratio", type=float, default=None, help="fraction of sampled goals relabelled (future)")
    p.add_argument("--hidden", default=None, help="hidden layer sizes, comma separated")
    p.add_argument("--policy-delay", type=int, default=None, help="actor update every N critic updates")
    p.add_argument("--demo-episodes", type=int, default=None,
                   help="act with the env's scripted baseline for this many episodes per world at the start of the "
                        "session: the replay buffer starts with its transitions (magwarp.training.demos)")
    p.add_argument("--demo-share", type=float, default=None,
                   help="share of the worlds, in [0, 1), that act with the scripted baseline for the whole session "
                        "(demonstrations in every minibatch; the success statistics count the other worlds)")
    p.add_argument("--demo-bc", type=float, default=None,
                   help="weight of a Q-filtered behaviour-cloning term on the demonstrations in the actor loss "
                        "(0: none; needs --demo-episodes or --demo-share)")
    p.add_argument("--critic-impl", choices=CRITIC_IMPLS, default=None,
                   help="the twin critics as one ensemble network (both Q heads in one batched matmul per layer) or "
                        "as two MLPs (the same maths; checkpoints of either layout load into the other)")
    p.add_argument("--adam", choices=("fused", "foreach"), default=None,
                   help="Adam implementation: fused (one kernel per optimiser step) or foreach")
    p.add_argument("--amp", choices=("off", "bf16"), default=None,
                   help="bf16 autocast of the networks' matmuls in the updates and the rollout (outputs in float32)")
    p.add_argument("--compile", choices=("off", "on"), default=None,
                   help="torch.compile the update's losses (forward and backward; the compilation counts against "
                        "the budget)")
    p.add_argument("--cuda-graph", choices=("auto", "on", "off"), default="auto",
                   help="replay each update as a captured CUDA graph (auto: on CUDA devices, off under torchrun)")
    p.add_argument("--overlap", choices=("auto", "on", "off"), default="auto",
                   help="run the env step of iteration t and the updates on the steps up to t - 1 at once, on two "
                        "CUDA streams (one-step-stale samples; auto: on for one CUDA device, off on the CPU and under "
                        "torchrun; on, on the CPU: the same schedule, serially)")
    p.add_argument("--async-eval", choices=("on", "off"), default="off",
                   help="with --overlap: run the periodic evaluation on a CUDA stream of its own beside training, on a "
                        "copy of the policy, and record it when done (its process seconds: when its result is read)")
    return p.parse_args(argv)


def resolve_args(args: argparse.Namespace) -> argparse.Namespace:
    args = resolve_run_args(args, PRESETS, DEFAULT_ENV, "sac_her")
    for name in ("updates_per_step", "policy_delay", "batch_size", "num_envs"):
        if int(getattr(args, name)) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be a positive integer, got {getattr(args, name)!r}")
    if not (math.isfinite(args.demo_bc) and args.demo_bc >= 0):
        raise ValueError(f"--demo-bc must be a finite weight >= 0, got {args.demo_bc!r}")
    if args.demo_bc > 0 and not (args.demo_episodes or args.demo_share):
        raise ValueError(f"--demo-bc {args.demo_bc} clones demonstrations: give --demo-episodes or --demo-share too")
    if args.updates_per_step % args.policy_delay:
        raise ValueError(f"--updates-per-step ({args.updates_per_step}) must be a multiple of --policy-delay "
                         f"({args.policy_delay}): an update unit is policy_delay critic updates and one actor update")
    return args


# ------------------------------------------------------------------------------------------------ replay buffer
class HerReplayBuffer:
    """``[capacity, num_envs]`` rings on the device; future-strategy HER over each env's episode storage.

    Every slot remembers its episode id (a per-env counter); ``ep_end[e, id % (capacity + 1)]`` holds the global
    step of that episode's last transition (a large number while it runs). At most ``capacity`` episodes of one env
    touch the window, so ``capacity + 1`` id slots never alias. With ``track_demos`` every slot also records whether
    a scripted baseline chose its action (:mod:`magwarp.training.demos`): samples then carry ``demo`` (1.0 or 0.0).
    """

    def __init__(self, capacity: int, num_envs: int, dims: dict[str, int], flag_keys: list[str], device,
                 track_demos: bool = False):
        T, N, dev = int(capacity), int(num_envs), device
        self.T, self.N, self.device, self.flag_keys = T, N, dev, list(flag_keys)
        self.data = {k: torch.zeros(T, N, d, device=dev) for k, d in dims.items()}
        self.reward = torch.zeros(T, N, device=dev)
        self.terminated = torch.zeros(T, N, dtype=torch.bool, device=dev)
        self.flags = {k: torch.zeros(T, N, dtype=torch.bool, device=dev) for k in self.flag_keys}
        self.ep_id = torch.zeros(T, N, dtype=torch.int64, device=dev)
        self.demo = torch.zeros(T, N, dtype=torch.bool, device=dev) if track_demos else None
        self.cur_id = torch.zeros(N, dtype=torch.int64, device=dev)
        self.ep_end = torch.full((N, T + 1), 2**62, dtype=torch.int64, device=dev)
        self.g = 0  # global step count (host int: no sync)

    @property
    def size(self) -> int:
        return min(self.g, self.T)

    @torch.no_grad()
    def add(self, obs: dict, action, reward, next_obs: dict, terminated, done, info: dict, demo=None) -> None:
        """One batched step; ``demo`` ``[N]`` (bool): the worlds whose action the scripted baseline chose."""
        i = self.g % self.T
        if self.demo is not None:
            if demo is None:
                raise ValueError("this buffer tracks demonstrations: pass demo=[num_envs] bool to add()")
            self.demo[i] = demo
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
    def sample(self, batch: int, her_ratio: float, compute_reward, upto: int | None = None):
        """``batch`` transitions drawn uniformly over (env, step), goals relabelled with ``her_ratio``.

        ``upto``: sample only global steps ``< upto`` (default: all added), the future goals included; the oldest
        step still stored (``g - capacity``) bounds the window from below. With an add in flight on another stream
        (``--overlap``), ``upto = g - 1`` keeps the sample off the slot it writes (which held step ``g - 1 -
        capacity``, outside the window) and off the step it writes. What the sample reads of the in-flight add's
        episode bookkeeping reads the same either side of the write: ``ep_end`` of the running episode changes from
        "running" to its last step ``g - 1``, both clamped to ``upto - 1``; the column the add clears belongs to an
        episode id no sampled step carries (ids of at most ``capacity`` steps, ``capacity + 1`` columns)."""
        upto = self.g if upto is None else int(upto)
        g0 = self.g - self.size  # global step of the oldest stored slot
        size = upto - g0
        if not (0 < size and upto <= self.g):
            raise ValueError(f"cannot sample steps [{g0}, {upto}) of a buffer holding [{g0}, {self.g}): "
                             "nothing committed there")
        gt = g0 + torch.randint(size, (batch,), device=self.device)
        e = torch.randint(self.N, (batch,), device=self.device)
        i = gt % self.T
        out = {k: v[i, e] for k, v in self.data.items()}
        reward, terminated = self.reward[i, e], self.terminated[i, e]
        flags = {k: v[i, e] for k, v in self.flags.items()}
        # Future strategy: a later step of the same episode (up to its end, or the newest step while it runs).
        end = self.ep_end[e, self.ep_id[i, e] % (self.T + 1)].clamp(max=upto - 1)
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
        if self.demo is not None:
            out["demo"] = self.demo[i, e].float()
        return out


class SacLearner:
    """The networks, their optimisers and the SAC update (clipped double Q, auto-tuned entropy temperature).

    :meth:`learn` takes one relabelled sample of ``U x batch_size`` transitions, normalises its observations once
    (the normaliser does not move while it learns), stages it as ``U`` minibatches packed in one tensor, and runs
    ``U`` critic updates (an actor and temperature update after every ``policy_delay`` of them). Each update picks its
    minibatch through a device counter (one ``index_select``), so the same code runs eagerly or, on CUDA, as one
    captured graph replayed ``U / policy_delay`` times: no Python or kernel-launch cost per update beyond the replay
    call. An update is latency-bound at the preset's sizes (many small kernels), so the options that matter cut
    kernels: ``--critic-impl ensemble`` (both Q heads in one batched matmul per layer), ``--adam fused`` (one kernel
    per optimiser step instead of a dozen foreach ones); ``--amp bf16`` runs the networks' matmuls in bf16,
    ``--compile on`` compiles the losses (their small ops fused).
    ``benchmarks/sac_update.py`` times them.
    """

    def __init__(self, n_obs: int, n_act: int, args: argparse.Namespace, device: torch.device):
        hidden = [int(h) for h in str(args.hidden).split(",")]
        self.args, self.device = args, device
        self.n_obs, self.n_act = n_obs, n_act
        def option(name: str):  # options a run saved before they existed fall back to the preset's defaults
            return getattr(args, name, None) or PRESETS["default"][name]

        amp = option("amp")
        self.critic_impl = option("critic_impl")
        self.fused_adam = option("adam") == "fused"
        self.actor = Actor(n_obs, n_act, hidden, amp).to(device)
        self.critic = make_critic(self.critic_impl, n_obs + n_act, hidden, amp).to(device)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.log_alpha = torch.full((), float(args.init_alpha), device=device).log().requires_grad_(True)
        self.target_entropy = -float(n_act)
        self.obs_rms = RunningMeanStd(n_obs, device, clip=5.0)
        self.graphed = args.cuda_graph == "on" or (args.cuda_graph == "auto" and device.type == "cuda"
                                                   and dist.world_size() == 1)
        if self.graphed and device.type != "cuda":
            raise ValueError(f"--cuda-graph on needs a CUDA device, got {device}")
        if self.graphed and dist.world_size() > 1:
            raise ValueError("--cuda-graph on is not supported under torchrun (gradients are all-reduced between "
                             "updates): use --cuda-graph auto or off")
        params = (self.actor.parameters(), self.critic.parameters(), [self.log_alpha])
        self.actor_opt, self.critic_opt, self.alpha_opt = self.optimizers = [
            torch.optim.Adam(p, lr=args.lr, fused=self.fused_adam) for p in params]
        self._configure_optimizers()
        self.compiled = option("compile") == "on"
        if self.compiled:
            import torch._inductor.config as inductor_config

            inductor_config.fallback_random = True  # the actor's noise from torch's generator, as eager draws it
        compile_fn = torch.compile if self.compiled else (lambda f: f)
        self._critic_loss_fn, self._actor_losses_fn = compile_fn(self._critic_loss), compile_fn(self._actor_losses)
        self.stage = torch.zeros(0, device=device)  # [U, batch, columns]: the staged minibatches (see _columns)
        self._columns: dict[str, slice | int] = {}
        self.cursor = torch.zeros(1, dtype=torch.int64, device=device)
        self._graph = None  # (torch.cuda.CUDAGraph, its static loss outputs) once captured

    # ---- state
    def tensors(self) -> list[torch.Tensor]:
        """Every learned tensor (weights, target weights, temperature, normaliser): what ranks must agree on."""
        return [*self.actor.parameters(), *self.critic.parameters(), *self.critic_target.parameters(), self.log_alpha,
                *self.obs_rms.buffers()]

    def state_dict(self) -> dict:
        return {"actor": self.actor.state_dict(), "critic": self.critic.state_dict(),
                "critic_target": self.critic_target.state_dict(), "log_alpha": self.log_alpha.detach(),
                "actor_opt": self.actor_opt.state_dict(), "critic_opt": self.critic_opt.state_dict(),
                "alpha_opt": self.alpha_opt.state_dict(), "obs_rms": self.obs_rms.state_dict()}

    def load_state_dict(self, ckpt: dict) -> None:
        """A checkpoint's networks and optimisers; a critic saved in the other layout (``--critic-impl``: a
        checkpoint written before the ensemble has two MLPs ``q1``/``q2``) is converted, its Adam moments too."""
        where = getattr(self.args, "resume", None) or "the checkpoint"
        try:
            have = critic_layout(ckpt["critic"])
            if have != self.critic_impl:
                ckpt = {**ckpt, "critic": convert_critic_state(ckpt["critic"], self.critic_impl),
                        "critic_target": convert_critic_state(ckpt["critic_target"], self.critic_impl),
                        "critic_opt": convert_critic_optimizer(ckpt["critic_opt"], have, self.critic_impl)}
            for name in ("actor", "critic", "critic_target", "obs_rms"):
                getattr(self, name).load_state_dict(ckpt[name])
        except (KeyError, ValueError, RuntimeError) as e:
            raise ValueError(f"cannot load the SAC networks of {where}: {type(e).__name__}: {e}") from None
        with torch.no_grad():
            self.log_alpha.copy_(ckpt["log_alpha"])
        for name in ("actor_opt", "critic_opt", "alpha_opt"):
            getattr(self, name).load_state_dict(ckpt[name])
        self._configure_optimizers()  # the saved run may have been eager or graphed, its Adam fused or not

    def _configure_optimizers(self) -> None:
        configure_adam(self.optimizers, self.graphed, self.device, fused=self.fused_adam)

    def set_lr(self, value: float) -> None:
        set_lr(self.optimizers, value)

    def norm(self, o: dict) -> torch.Tensor:
        return self.obs_rms.normalize(torch.cat([o[k] for k in OBS_KEYS], -1))

    # ---- the update
    def _stage(self, sample: dict[str, torch.Tensor], num_minibatches: int) -> None:
        """Normalise and pack ``sample`` as ``[U, batch, columns]``: ``[x | action]`` (the critic's input, ``x`` the
        normalised observation), ``x2`` (the next one), reward, not-done and (with demonstrations) demo flags."""
        x = self.norm({k: sample[k] for k in OBS_KEYS})
        x2 = self.norm({k: sample["next_" + k] for k in OBS_KEYS})
        cols = [x, sample["action"].to(x.dtype), x2, sample["reward"].to(x.dtype)[:, None],
                (~sample["terminated"].bool()).to(x.dtype)[:, None]]
        o, a = self.n_obs, self.n_act
        self._columns = {"xa": slice(0, o + a), "x": slice(0, o), "action": slice(o, o + a),
                         "x2": slice(o + a, 2 * o + a), "reward": 2 * o + a, "not_done": 2 * o + a + 1}
        if "demo" in sample:
            self._columns["demo"] = 2 * o + a + 2
            cols.append(sample["demo"].to(x.dtype)[:, None])
        width = sum(c.shape[-1] for c in cols)
        shape = (num_minibatches, x.shape[0] // num_minibatches, width)
        if self.stage.shape == shape:
            torch.cat(cols, -1, out=self.stage.view(-1, width))  # same storage: what a captured graph reads
        else:
            self.stage = torch.cat(cols, -1).view(shape)
            self._graph = None

    def _next_minibatch(self) -> dict[str, torch.Tensor]:
        row = self.stage.index_select(0, self.cursor)[0]
        self.cursor.add_(1)
        return {k: row[:, c] for k, c in self._columns.items()}  # column views: no copies

    def _critic_loss(self, mb: dict[str, torch.Tensor]) -> torch.Tensor:
        """The clipped double-Q regression loss of the minibatch (``--compile on`` compiles this function)."""
        with torch.no_grad():
            alpha = self.log_alpha.exp()
            a2, logp2 = self.actor(mb["x2"])
            q_next = q_min(self.critic_target(torch.cat([mb["x2"], a2], -1)))
            target = mb["reward"] + self.args.gamma * mb["not_done"] * (q_next - alpha * logp2)
        return q_regression_loss(self.critic(mb["xa"]), target)

    def _actor_losses(self, mb: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """The policy loss (through the critic, whose weights the caller freezes) and the temperature's loss
        (``--compile on`` compiles this function)."""
        x = mb["x"]
        a, logp = self.actor(x)
        q_pi = q_min(self.critic(torch.cat([x, a], -1)))
        pi_loss = (self.log_alpha.exp().detach() * logp - q_pi).mean()
        if self.args.demo_bc > 0:
            pi_loss = pi_loss + self.args.demo_bc * self._bc_loss(x, mb, q_pi.detach())
        alpha_loss = -(self.log_alpha * (logp.detach() + self.target_entropy)).mean()
        return pi_loss, alpha_loss

    def _critic_step(self, mb: dict[str, torch.Tensor]) -> torch.Tensor:
        q_loss = self._critic_loss_fn(mb)
        # Gradients set to None, not zeroed: the backward pass then writes them (no zero and accumulate kernels); a
        # captured graph allocates them from its pool and every replay writes the same buffers.
        self.critic_opt.zero_grad(set_to_none=True)
        q_loss.backward()
        dist.average_gradients(self.critic.parameters())  # torchrun: the mean over all ranks' minibatches
        self.critic_opt.step()
        with torch.no_grad():  # Polyak averaging of the target critic, one fused call
            torch._foreach_lerp_(list(self.critic_target.parameters()), list(self.critic.parameters()), self.args.tau)
        return q_loss.detach()

    def _actor_step(self, mb: dict[str, torch.Tensor]) -> torch.Tensor:
        """The policy and the temperature from one backward pass: the policy loss reaches the actor only (the critic's
        weights are frozen, the temperature detached), the temperature's loss only ``log_alpha`` (the log-probability
        detached), so the sum's gradients are each loss's own."""
        self.critic.requires_grad_(False)  # the policy loss differentiates through Q into the actor only
        pi_loss, alpha_loss = self._actor_losses_fn(mb)
        self.actor_opt.zero_grad(set_to_none=True)
        self.alpha_opt.zero_grad(set_to_none=True)
        (pi_loss + alpha_loss).backward()
        dist.average_gradients([*self.actor.parameters(), self.log_alpha])
        self.actor_opt.step()
        self.alpha_opt.step()
        self.critic.requires_grad_(True)
        return pi_loss.detach()

    def _bc_loss(self, x: torch.Tensor, mb: dict[str, torch.Tensor], q_pi: torch.Tensor) -> torch.Tensor:
        """Behaviour cloning on the minibatch's demonstrations, Q-filtered (Nair et al. 2018, "Overcoming Exploration
        in Reinforcement Learning with Demonstrations", for DDPG + HER): the squared distance of the deterministic
        action to the demonstrated one, where the critic rates the demonstrated action above the policy's sample,
        summed over actions and averaged over the minibatch's demonstrations."""
        if "demo" not in mb:
            raise ValueError("--demo-bc needs demonstrations in the replay buffer (--demo-episodes or --demo-share)")
        with torch.no_grad():
            keep = mb["demo"] * (q_min(self.critic(x, mb["action"])) > q_pi).float()
        mean_action = self.actor(x, deterministic=True)[0]
        err = (mean_action - mb["action"]).square().sum(-1)
        return (keep * err).sum() / mb["demo"].sum().clamp_min(1.0)

    def _update_unit(self) -> dict[str, torch.Tensor]:
        """``policy_delay`` critic updates on consecutive minibatches, then one actor and temperature update."""
        for _ in range(self.args.policy_delay):
            mb = self._next_minibatch()
            q_loss = self._critic_step(mb)
        return {"loss_q": q_loss, "loss_pi": self._actor_step(mb)}

    def _capture(self) -> None:
        """Record one update unit as a CUDA graph (PyTorch's whole-network capture recipe): eager warm-up units on a
        side stream create the optimiser states and cuBLAS workspaces, the gradients are released so that the
        capture allocates them from the graph's pool, then the unit is captured. The warm-up's changes (weights,
        optimiser moments, random numbers) are undone, so a graphed run follows the eager one update for update."""
        tensors = [*self.actor.parameters(), *self.critic.parameters(), *self.critic_target.parameters(), self.log_alpha]
        saved = [t.detach().clone() for t in tensors]
        opt_saved = {id(v): v.clone() for opt in self.optimizers for st in opt.state.values() for v in st.values()
                     if isinstance(v, torch.Tensor)}
        rng = torch.cuda.get_rng_state(self.device)
        side = torch.cuda.Stream(self.device)
        side.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(side):
            for _ in range(3):
                self.cursor.zero_()
                self._update_unit()
        torch.cuda.current_stream(self.device).wait_stream(side)
        with torch.no_grad():
            for t, v in zip(tensors, saved):
                t.copy_(v)
            for opt in self.optimizers:  # moments and step counts as before (zero where the warm-up created them)
                for st in opt.state.values():
                    for v in st.values():
                        if isinstance(v, torch.Tensor) and id(v) in opt_saved:
                            v.copy_(opt_saved[id(v)])
                        elif isinstance(v, torch.Tensor):
                            v.zero_()
        torch.cuda.set_rng_state(rng, self.device)
        for opt in self.optimizers:
            opt.zero_grad(set_to_none=True)
        self.cursor.zero_()
        graph = torch.cuda.CUDAGraph()
        with gc_paused(), torch.cuda.graph(graph):
            out = self._update_unit()
        self._graph = (graph, out)

    def learn(self, sample: dict[str, torch.Tensor], num_minibatches: int) -> dict[str, torch.Tensor]:
        """``num_minibatches`` updates on ``sample`` split into equal minibatches; the last losses (device tensors)."""
        if num_minibatches % self.args.policy_delay:
            raise ValueError(f"{num_minibatches} minibatches is not a multiple of policy_delay {self.args.policy_delay}")
        if sample["action"].shape[0] % num_minibatches:
            raise ValueError(f"a sample of {sample['action'].shape[0]} transitions does not split into "
                             f"{num_minibatches} equal minibatches")
        self._stage(sample, num_minibatches)
        if self.graphed and self._graph is None:
            self._capture()
        self.cursor.zero_()
        out: dict[str, torch.Tensor] = {}
        for _ in range(num_minibatches // self.args.policy_delay):
            if self._graph is not None:
                self._graph[0].replay()
            else:
                out = self._update_unit()
        return self._graph[1] if self._graph is not None else out


def overlap_enabled(args: argparse.Namespace, device: torch.device) -> bool:
    """``--overlap``: auto is on for one CUDA device, off on the CPU and under torchrun; on runs the overlapped schedule
    (serially on the CPU); on under torchrun is refused (every update all-reduces its gradients)."""
    if args.overlap == "on" and dist.world_size() > 1:
        raise ValueError("--overlap on is not supported under torchrun (the updates all-reduce gradients between "
                         "the ranks): use --overlap auto or off")
    on = args.overlap == "on" or (args.overlap == "auto" and device.type == "cuda" and dist.world_size() == 1)
    if on and args.buffer_steps < 2:
        raise ValueError(f"--overlap needs --buffer-steps >= 2 (one slot is written while the learner samples the "
                         f"others), got {args.buffer_steps}")
    if getattr(args, "async_eval", "off") == "on" and not on:
        raise ValueError("--async-eval on runs beside the overlapped streams: it needs --overlap on (or auto on one "
                         "CUDA device)")
    return on


def _policy_snapshot(learner: SacLearner, streams: StreamPair, action_scale: torch.Tensor):
    """``--async-eval``: a function that copies the actor and normaliser on the current stream (the evaluation's),
    behind the learner's updates so far and ahead of its next ones, and returns the deterministic policy of the copy."""
    actor = copy.deepcopy(learner.actor).requires_grad_(False)
    rms = copy.deepcopy(learner.obs_rms)
    dst = [*actor.parameters(), *rms.buffers()]
    src = [*learner.actor.parameters(), *learner.obs_rms.buffers()]

    def snapshot():
        streams.join()  # the copy follows the learner's last update
        with torch.no_grad():
            torch._foreach_copy_(dst, src)
        streams.release()  # the learner's next update follows the copy
        return lambda o: actor(rms.normalize(flatten_obs(o)), deterministic=True)[0] * action_scale

    return snapshot


def _train(args: argparse.Namespace) -> dict:
    main_rank, world = dist.is_main(), dist.world_size()
    startup: dict[str, float] = {}  # seconds since the process started at each point of the start-up (run.json)

    def mark(name: str) -> None:
        startup.setdefault(name, round(time.perf_counter() - PROCESS_START, 3))

    mark("imports")
    seed, env, base, n_obs, n_act, action_scale = open_env(args)
    device = base.device  # the env's device, with its index (cuda -> cuda:0)
    N = args.num_envs
    space = base.single_observation_space
    overlap = overlap_enabled(args, device)
    mark("train_env")

    learner = SacLearner(n_obs, n_act, args, device)
    actor, norm = learner.actor, learner.norm
    global_step, updates, wall_before, target_state = 0, 0, 0.0, None
    if args.resume:
        ckpt = load_checkpoint(args.resume, device)
        learner.load_state_dict(ckpt)
        global_step, updates, wall_before = ckpt["global_step"], ckpt["updates"], ckpt["wall_s"]
        target_state = ckpt.get("target")
        if main_rank:
            print(f"resumed from {args.resume} at step {global_step:,} ({updates:,} updates)")
    dist.broadcast_(learner.tensors())  # every rank starts from rank 0's weights
    mark("learner")

    obs, info = env.reset(seed=seed)
    # Collision flags the env's compute_reward reads: keep them with every transition (learned from one step, which
    # also compiles the kernels and captures the step graph before the clock starts).
    probe = {k: v.shape for k, v in env.step(torch.zeros(N, n_act, device=device))[4].items()
             if k.endswith("collision") and isinstance(v, torch.Tensor)}
    flag_keys = sorted(probe)
    obs, _ = env.reset(seed=seed)
    mark("first_env_step")
    dims = {}
    for k in OBS_KEYS:
        dims[k] = dims["next_" + k] = int(space[k].shape[0])
    dims["action"] = n_act
    demos = ScriptedDemos(base, action_scale, args.demo_episodes, args.demo_share)
    rows = demos.learner_rows  # the learner's worlds (all without a demo share): what the statistics count
    buffer = HerReplayBuffer(args.buffer_steps, N, dims, flag_keys, device, track_demos=demos.enabled)

    # --overlap: the env step of iteration t and the updates on steps <= t - 1 run on two CUDA streams at once
    streams = StreamPair(device, overlap)
    async_eval = args.async_eval == "on"  # the periodic evaluation on a third stream (its env is built there)
    session = Session(args, "sac-her", device, target_state, num_agents=N - demos.worlds,
                      eval_stream=streams.side_stream() if async_eval else None)
    tracker = session.tracker
    streams.time_in(session.phases)
    snapshot = _policy_snapshot(learner, streams, action_scale) if async_eval else None
    mark("eval_env")

    def act(o):  # the deterministic policy (what policy.pt runs), after the learner's last update
        streams.join()
        return actor(norm(o), deterministic=True)[0] * action_scale

    def save_all(summary: dict | None = None) -> None:
        streams.join()
        dist.check_in_sync(learner.tensors())  # torchrun: every rank holds rank 0's
        if not main_rank:
            return
        state = {"algo": "sac-her", "args": {k: v for k, v in vars(args).items() if k != "resume"},
                 **learner.state_dict(), "global_step": global_step, "updates": updates,
                 "wall_s": session.timer.total, "target": session.target.state()}
        save_checkpoint(os.path.join(args.out, "checkpoint.pt"), state)
        save_policy(os.path.join(args.out, "policy.pt"), actor.mean_net(), learner.obs_rms, action_scale, squash="tanh",
                    env_id=args.env_id, metadata={"algo": "sac-her", "env_kwargs": args.env_kwargs,
                                                  "eval_env_kwargs": args.eval_env_kwargs,
                                                  "global_step": global_step, "wall_s": session.timer.total,
                                                  **(summary or {})})

    losses: dict[str, torch.Tensor] = {}
    env_steps = 0  # batched steps of this session
    # A resumed run has trained networks: it acts with them at once and learns as soon as the buffer has a few steps.
    warmup = min(args.learning_starts, 5) if args.resume else args.learning_starts
    def tail() -> dict:  # the log row's end (read only when a row is written)
        streams.join()
        row = {"alpha": float(learner.log_alpha.detach().exp()), **{k: float(v) for k, v in losses.items()}}
        if demos.enabled:
            row["demo_share"] = demos.share_at(env_steps)
        if getattr(base, "curriculum_level", None) is not None:  # PushWithObstacles' wall curriculum: mean level
            row["curriculum_level"] = float(base.curriculum_level.float().mean())
        return row

    stop = session.start(wall_before, global_step)
    mark("clock_start")
    timer, total = session.timer, session.total
    streams.start_clock()
    # One iteration, no host sync (the log, evaluation and checkpoint sync when due): the action of step t (after the
    # updates of iteration t - 1), the env step t and its buffer add, then the updates on steps <= t - streams.lag
    # (t with --overlap off; t - 1 with it, while the env steps: a one-step-stale schedule, as asynchronous off-policy
    # learners run). The normaliser learns step t's observation after acting on it, before the updates.
    while not stop:
        with torch.no_grad():
            with streams.act("policy"):
                if env_steps < warmup and not args.resume:
                    action = torch.rand(N, n_act, device=device) * 2 - 1
                else:
                    action, _ = actor(norm(obs))
                if demos.enabled:
                    action = demos(obs, action, env_steps)
                learner.obs_rms.update(flatten_obs(obs))
            with streams.env("env"):
                next_obs, reward, terminated, truncated, info = env.step(action * action_scale)
            with streams.env("buffer"):
                done = terminated | truncated
                buffer.add(obs, action, reward, info["final_obs"], terminated, done, info,
                           demos.acting(env_steps) if demos.enabled else None)
                tracker.update(rows(reward), rows(terminated), rows(truncated), {k: rows(v) for k, v in info.items()})
            obs = next_obs
        env_steps += 1
        global_step += N * world
        committed = buffer.g - streams.lag  # steps the learner may sample (an add in flight: not the newest)
        if committed >= max(warmup, 1):
            U = args.updates_per_step  # one relabelling call for all of this step's minibatches
            with streams.learn("sample"):
                if args.lr_schedule == "linear":  # the paper's schedule: lr falls linearly to 0 over the budget
                    done_frac = global_step / total if total else (timer.total / (timer.already + timer.limit)
                                                                  if timer.limit else 0.0)
                    (done_frac,) = dist.agree(done_frac)  # rank 0's clock
                    learner.set_lr(args.lr * max(1.0 - done_frac, 0.0))
                sample = buffer.sample(U * args.batch_size, args.her_ratio, base.compute_reward, upto=committed)
            with streams.learn("update"):
                losses = learner.learn(sample, U)
            updates += U
            mark("first_update")
        streams.end_iteration()
        stop, checkpoint = session.step_done(global_step, act, {"updates": updates}, tail, snapshot)
        if checkpoint:
            save_all()
    streams.join()
    summary = session.finish(env, act, global_step, seed, save_all, "SAC+HER",
                             extra={"updates": updates, "overlap": overlap, "startup_s": startup})
    env.close()
    return summary


def train(args: argparse.Namespace) -> dict:
    """SAC + HER: train until the budget is spent; returns the summary (final success rate, env steps, wall seconds,
    time to target). Under torchrun, every rank calls this (see :mod:`magwarp.training.distributed`)."""
    return run_training(args, resolve_args, _train)


main = entry_point(parse_args, train)  # main(argv) -> 0, what `python -m` and torchrun run


if __name__ == "__main__":
    sys.exit(main())
