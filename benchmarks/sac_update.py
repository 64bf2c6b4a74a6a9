"""The cost of one SAC+HER update (:class:`magwarp.training.sac_her.SacLearner`) at the Push-Box preset's sizes, for
the update options side by side: the twin critics as two MLPs or one ensemble (``--critic-impl``), foreach or fused
Adam (``--adam``), bf16 autocast (``--amp``), torch.compile of the losses (``--compile``), and (on CUDA) graphed or
eager.

Each (variant, batch size) builds a learner (3 x 256 hidden, seed 0), stages one random sample of ``U`` minibatches
(``--minibatches``, the preset's 64 updates per env step) and times ``learn()`` (U updates; on CUDA one captured graph
replayed U times, on the CPU eager) after a first call that captures or warms up: ms per update and updates per
second. With the profiler (``--profile``, on by default) one more ``learn()`` call is traced: kernels per update and
their summed device time against the wall time per update (on CUDA: kernels launched by the graph's replays; their
summed time far below the wall time means the update is latency-bound, not FLOP-bound). On the CPU the count is of
leaf ATen ops (an eager update's op count, what would be kernels on a GPU).

    python benchmarks/sac_update.py --device cuda:0 --json sac_update_gpu.json     # every variant and batch size
    python benchmarks/sac_update.py --device cuda:0 --variants base,default,compile@4096 --json sac_update_gpu.json
    python benchmarks/sac_update.py --smoke                                          # CPU check, small sizes

Network sizes: Push-Box (``magwarp/PushBox-v0``, one mover without rotation or jerk): observation 4, achieved and
desired goal 2 each (8 network inputs, as ``magwarp/pretrained/pushbox_sac.pt``'s ``obs_mean``), 2 actions;
``--task pusht``: Push-T's 6 + 4 + 4 inputs and 2 actions (``magwarp/envs/push.py``, ``_observation_space``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import torch  # noqa: E402

from common import finish, start_run  # noqa: E402

# (observation, achieved goal, desired goal, actions) per task: see the module docstring
TASK_DIMS = {"pushbox": (4, 2, 2, 2), "pusht": (6, 4, 4, 2)}
# name -> SacLearner options (the command-line names of magwarp.training.sac_her); "main" is main's update before
# this work, "base" today's update with main's networks and optimiser (two MLPs, foreach Adam), "default" the
# ensemble with fused Adam (the preset when this benchmark was written; the preset is now "fused": measured faster)
VARIANTS = {
    "main": {"critic_impl": "pair", "adam": "foreach", "amp": "off"},  # main's update (see _main_learner_class)
    "base": {"critic_impl": "pair", "adam": "foreach", "amp": "off"},
    "ensemble": {"critic_impl": "ensemble", "adam": "foreach", "amp": "off"},
    "fused": {"critic_impl": "pair", "adam": "fused", "amp": "off"},
    "default": {"critic_impl": "ensemble", "adam": "fused", "amp": "off"},
    "bf16": {"critic_impl": "ensemble", "adam": "fused", "amp": "bf16"},
    "compile": {"critic_impl": "ensemble", "adam": "fused", "amp": "off", "compile": "on"},
    "default-eager": {"critic_impl": "ensemble", "adam": "fused", "amp": "off", "cuda_graph": "off"},
    "main-eager": {"critic_impl": "pair", "adam": "foreach", "amp": "off", "cuda_graph": "off"},
}
COLUMNS = ["device", "variant", "batch", "graphed", ("first_call_s", "first call s"), ("ms_per_update", "ms/update"),
           ("updates_per_s", "updates/s"),
           ("kernels_per_update", "kernels/update"), ("kernel_ms_per_update", "kernel ms/update"),
           ("busy_share", "kernel time/wall"), ("eager_kernels_per_update", "eager kernels"), ("loss_q", "loss_q")]


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize(device)


def _main_learner_class():
    """``SacLearner`` with main's update as of commit 3b4b43c (before this benchmark's options), for the ``main``
    variant: every staged key picked by its own ``index_select``, the observations normalised in every update, the
    gradients zeroed and accumulated, the temperature from its own backward pass (with two MLPs and foreach Adam)."""
    import torch.nn.functional as F

    from magwarp.training import sac_her
    from magwarp.training.common import OBS_KEYS

    class MainLearner(sac_her.SacLearner):
        def _stage(self, sample, num_minibatches):
            if not isinstance(self.stage, dict):
                self.stage = {}
            for k, v in sample.items():
                v = v.reshape(num_minibatches, -1, *v.shape[1:])
                if k in self.stage and self.stage[k].shape == v.shape:
                    self.stage[k].copy_(v)
                else:
                    self.stage[k], self._graph = v.clone(), None

        def _next_minibatch(self):
            mb = {k: v.index_select(0, self.cursor)[0] for k, v in self.stage.items()}
            self.cursor.add_(1)
            return mb

        def _update_unit(self):
            for _ in range(self.args.policy_delay):
                mb = self._next_minibatch()
                x = self.norm({k: mb[k] for k in OBS_KEYS})
                x2 = self.norm({k: mb["next_" + k] for k in OBS_KEYS})
                alpha = self.log_alpha.exp().detach()
                with torch.no_grad():
                    a2, logp2 = self.actor(x2)
                    q1t, q2t = self.critic_target(x2, a2)
                    not_done = (~mb["terminated"]).float()
                    target = mb["reward"] + self.args.gamma * not_done * (torch.min(q1t, q2t) - alpha * logp2)
                q1, q2 = self.critic(x, mb["action"])
                q_loss = F.mse_loss(q1, target) + F.mse_loss(q2, target)
                self.critic_opt.zero_grad(set_to_none=False)
                q_loss.backward()
                self.critic_opt.step()
                with torch.no_grad():
                    torch._foreach_lerp_(list(self.critic_target.parameters()), list(self.critic.parameters()),
                                         self.args.tau)
            self.critic.requires_grad_(False)
            a, logp = self.actor(x)
            pi_loss = (self.log_alpha.exp().detach() * logp - torch.min(*self.critic(x, a))).mean()
            self.actor_opt.zero_grad(set_to_none=False)
            pi_loss.backward()
            self.actor_opt.step()
            self.critic.requires_grad_(True)
            alpha_loss = -(self.log_alpha * (logp.detach() + self.target_entropy)).mean()
            self.alpha_opt.zero_grad(set_to_none=False)
            alpha_loss.backward()
            self.alpha_opt.step()
            return {"loss_q": q_loss.detach(), "loss_pi": pi_loss.detach()}

    return MainLearner


def make_learner(variant: str, batch: int, hidden: str, dims: tuple[int, ...], device: str):
    """A :class:`SacLearner` with the preset's options and ``variant``'s (seed 0)."""
    from magwarp.training import sac_her

    opts = VARIANTS[variant]
    argv = ["--device", device, "--total-steps", "1", "--hidden", hidden, "--batch-size", str(batch),
            "--cuda-graph", opts.get("cuda_graph", "auto")]
    for k in ("critic_impl", "adam", "amp", "compile"):
        argv += ["--" + k.replace("_", "-"), opts.get(k, "off")]
    args = sac_her.resolve_args(sac_her.parse_args(argv))
    torch.manual_seed(0)
    n_obs = dims[0] + dims[1] + dims[2]
    cls = _main_learner_class() if variant.startswith("main") else sac_her.SacLearner
    return cls(n_obs, dims[3], args, torch.device(device))


def make_sample(n: int, dims: tuple[int, ...], device: str, seed: int = 0) -> dict[str, torch.Tensor]:
    """A relabelled replay sample of ``n`` transitions as :meth:`HerReplayBuffer.sample` returns it (random values)."""
    g = torch.Generator(device=device).manual_seed(seed)
    out = {}
    for k, d in zip(("observation", "achieved_goal", "desired_goal"), dims[:3]):
        out[k] = torch.randn(n, d, device=device, generator=g)
        out["next_" + k] = torch.randn(n, d, device=device, generator=g)
    out["action"] = torch.rand(n, dims[3], device=device, generator=g) * 2 - 1
    out["reward"] = -(torch.rand(n, device=device, generator=g) < 0.9).float()
    out["terminated"] = torch.zeros(n, dtype=torch.bool, device=device)
    return out


# ATen ops that launch no compute (views, allocations, dtype/alias bookkeeping, host reads of a scalar)
_NO_COMPUTE = {"aten::as_strided", "aten::view", "aten::_unsafe_view", "aten::reshape", "aten::select", "aten::slice",
               "aten::expand", "aten::t", "aten::transpose", "aten::permute", "aten::unsqueeze", "aten::squeeze",
               "aten::detach", "aten::alias", "aten::empty", "aten::empty_strided", "aten::empty_like",
               "aten::resolve_conj", "aten::resolve_neg", "aten::result_type", "aten::_local_scalar_dense",
               "aten::broadcast_tensors", "aten::scalar_tensor", "aten::resize_", "aten::to", "aten::lift_fresh",
               "aten::split", "aten::chunk", "aten::narrow", "aten::item"}


def _leaf_ops(events) -> tuple[int, float]:
    """CPU trace: ATen ops that compute, with no ATen op below them (count, summed self time in ms). A proxy for a
    GPU's kernels only: the CPU's matmuls run below ATen and its foreach ops loop over the tensors."""
    count, ms = 0, 0.0
    for e in events:
        if (e.name.startswith("aten::") and e.name not in _NO_COMPUTE
                and not any(c.name.startswith("aten::") for c in e.cpu_children)):
            count += 1
            ms += e.self_cpu_time_total / 1000.0
    return count, ms


def _device_kernels(events) -> tuple[int, float]:
    """CUDA trace: kernels, memsets and copies on the device (count, summed device time in ms)."""
    from torch.autograd import DeviceType

    count, ms = 0, 0.0
    for e in events:
        if getattr(e, "device_type", None) == DeviceType.CUDA:
            count += 1
            ms += getattr(e, "device_time", getattr(e, "cuda_time", 0.0)) / 1000.0
    return count, ms


def _trace(fn, device: str) -> tuple[int, float]:
    from torch.profiler import ProfilerActivity, profile

    cuda = device.startswith("cuda")
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    _sync(device)
    with profile(activities=activities) as prof:
        fn()
        _sync(device)
    return (_device_kernels if cuda else _leaf_ops)(prof.events())


def profile_learn(learner, sample: dict, minibatches: int, device: str) -> dict[str, float | int | str]:
    """One traced ``learn()`` call: kernels (CUDA; the graph's replays when graphed) or compute ops (CPU) per update
    and their summed time; for a graphed learner also one eager update unit (``eager_kernels_per_update``)."""
    out: dict[str, float | int | str] = {}
    try:
        count, ms = _trace(lambda: learner.learn(sample, minibatches), device)
        out.update(kernels_per_update=count / minibatches, kernel_ms_per_update=ms / minibatches)
        if learner.graphed:
            learner.cursor.zero_()  # the unit reads the first staged minibatch
            count, ms = _trace(learner._update_unit, device)
            units = learner.args.policy_delay
            out.update(eager_kernels_per_update=count / units, eager_kernel_ms_per_update=ms / units)
    except Exception as e:  # a profiler that cannot trace here: the timings stand without the counts
        out["profile_error"] = f"{type(e).__name__}: {e}"
    return out


def measure(variant: str, batch: int, args: argparse.Namespace, device: str) -> dict:
    dims = TASK_DIMS[args.task]
    learner = make_learner(variant, batch, args.hidden, dims, device)
    sample = make_sample(batch * args.minibatches, dims, device)
    t = time.perf_counter()
    losses = learner.learn(sample, args.minibatches)  # captures the graph (CUDA), compiles, or warms up
    _sync(device)
    first_s = time.perf_counter() - t
    t = time.perf_counter()
    for _ in range(args.rounds):
        losses = learner.learn(sample, args.minibatches)
    _sync(device)
    ms = 1000.0 * (time.perf_counter() - t) / (args.rounds * args.minibatches)
    row = {"device": device, "task": args.task, "variant": variant, "critic_impl": learner.critic_impl,
           "adam": "fused" if learner.fused_adam else "foreach", "amp": learner.actor.amp,
           "compile": "on" if learner.compiled else "off", "batch": batch,
           "minibatches": args.minibatches, "hidden": args.hidden, "graphed": learner.graphed,
           "rounds": args.rounds, "first_call_s": first_s, "ms_per_update": ms, "updates_per_s": 1000.0 / ms,
           "loss_q": float(losses["loss_q"]), "loss_pi": float(losses["loss_pi"]),
           "matmul_precision": torch.get_float32_matmul_precision()}
    if args.profile:
        row.update(profile_learn(learner, sample, args.minibatches, device))
        if "kernel_ms_per_update" in row:
            row["busy_share"] = row["kernel_ms_per_update"] / ms
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: the CPU, and cuda:0 when present)")
    p.add_argument("--task", choices=sorted(TASK_DIMS), default="pushbox", help="network input and output sizes")
    p.add_argument("--batch-sizes", default="1024,4096,8192")
    p.add_argument("--variants", default=None,
                   help=f"comma separated, of {sorted(VARIANTS)} (default: all; --smoke: those the CPU runs fast)")
    p.add_argument("--minibatches", type=int, default=64, help="updates per learn() call (the preset's U)")
    p.add_argument("--hidden", default="256,256,256")
    p.add_argument("--rounds", type=int, default=5, help="timed learn() calls per (variant, batch)")
    p.add_argument("--no-profile", dest="profile", action="store_false", help="no kernel counts")
    p.add_argument("--smoke", action="store_true", help="CPU check: small sizes (overrides the sizes above)")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    if args.smoke:
        args.device, args.batch_sizes, args.minibatches, args.hidden, args.rounds = "cpu", "64,256", 4, "64,64", 2
        args.variants = args.variants or "main,base,ensemble,fused,default,bf16"
    batches = [int(b) for b in args.batch_sizes.split(",")]
    # "name" runs at every batch size, "name@4096/8192" at those only (compiling costs tens of seconds per size)
    variants: list[tuple[str, list[int]]] = []
    for spec in args.variants.split(",") if args.variants else list(VARIANTS):
        name, _, only = spec.partition("@")
        if name not in VARIANTS:
            raise SystemExit(f"unknown variant {name!r}: choose from {sorted(VARIANTS)}")
        variants.append((name, [int(b) for b in only.split("/")] if only else batches))
    info, devices = start_run(args.device)
    rows = []
    for device in devices:
        if device.startswith("cuda"):
            torch.set_float32_matmul_precision("high")  # what training sets on CUDA (make_env): TF32 matmuls
        for batch in sorted({b for _, sizes in variants for b in sizes}):
            for variant, sizes in variants:
                if batch not in sizes or ("cuda_graph" in VARIANTS[variant] and not device.startswith("cuda")):
                    continue  # eager is what the CPU runs anyway
                rows.append(measure(variant, batch, args, device))
                print(f"  {device} {variant:>14} batch {batch:>5}: {rows[-1]['ms_per_update']:.3f} ms/update",
                      flush=True)
    return finish(rows, COLUMNS, info, args.json)


if __name__ == "__main__":
    sys.exit(main())
