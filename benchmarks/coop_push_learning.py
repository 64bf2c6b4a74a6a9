"""Does SAC + HER learn CoopPush? Short runs of the paper runs named, then each policy's object progress.

Two movers must push a box that one cannot move (``magwarp/CoopPush-v0``); random exploration never moves it, so
hindsight relabelling has nothing to teach and ``coop_push_sac`` stayed at 0% (5 minutes on an H100). This trains the
named runs of :data:`magwarp.training.paper.PAPER_RUNS` for ``--minutes`` each (``--args``: extra training options,
e.g. smaller networks on the CPU), one after the other, then plays one episode per world (``--eval-envs`` worlds,
fresh seeds, deterministic policy) with each policy on the run's evaluation options (and on its training options
where they differ) and reports the success rate and the object progress: how much nearer its goal the object ends
than it started (m, mean over worlds; an episode cut by a collision counts where it ended). Rows for reference:
``zero`` (no action: the object stays, progress 0), ``untrained`` (a fresh actor's deterministic policy) and
``scripted`` (the line-up-and-push baseline); ``--clone-steps``: networks fitted to the baseline's transitions alone
(plain behaviour cloning: how much of it that many demonstrations give).

    python benchmarks/coop_push_learning.py --smoke                                   # CPU, a few minutes
    python benchmarks/coop_push_learning.py --device cpu --minutes 8 --num-envs 16 \\
        --args "--batch-size 256 --updates-per-step 8 --hidden 128,128" --json coop_learning_cpu.json
    python benchmarks/coop_push_learning.py --device cpu --runs "" --num-envs 16 --clone-steps 300,1500
    python benchmarks/coop_push_learning.py --device cuda:0 --minutes 5 --json coop_learning_gpu.json

Writes JSON (``--json``) with device, date, versions and command; prints a table.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import tempfile

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import finish, start_run  # noqa: E402

DEFAULT_RUNS = ("coop_push_sac", "coop_push_sac_demos")


@torch.no_grad()
def object_progress(env_id: str, env_kwargs: dict, policy, num_envs: int, device: str, seed: int) -> dict:
    """One episode per world: success rate, collision rate and mean object progress (m) of ``policy(env) -> act``."""
    from magwarp.training import make_env

    env, base = make_env(env_id, num_envs, device, seed, env_kwargs)
    act = policy(base)
    obs, _ = env.reset(seed=seed)
    d0 = (obs["achieved_goal"][:, :2] - obs["desired_goal"][:, :2]).norm(dim=-1)
    d_end = torch.zeros_like(d0)
    success = torch.zeros(num_envs, dtype=torch.bool, device=d0.device)
    collided = torch.zeros_like(success)
    ended = torch.zeros_like(success)
    for _ in range(int(base.max_episode_steps)):
        obs, _, terminated, truncated, info = env.step(act(obs))
        done = (terminated | truncated) & ~ended
        final = info["final_obs"]
        d = (final["achieved_goal"][:, :2] - final["desired_goal"][:, :2]).norm(dim=-1)
        d_end = torch.where(done, d, d_end)
        success |= done & info["is_success"]
        collided |= done & (info["mover_collision"] | info["wall_collision"])
        ended |= done
        if bool(ended.all()):
            break
    env.close()
    return {"success_rate": float(success.float().mean()), "collision_rate": float(collided.float().mean()),
            "object_progress_m": float((d0 - d_end)[ended].mean()), "start_distance_m": float(d0.mean()),
            "episodes": int(ended.sum())}


def _trained(path: str):
    from magwarp.evaluate import load_policy

    return lambda base: load_policy(path, base)


def _zero(base):
    return lambda obs: torch.zeros(base.num_envs, base.single_action_space.shape[0], device=base.device)


def _scripted(base):
    from magwarp.evaluate import scripted_policy

    return scripted_policy(base)


def cloned(env_id: str, env_kwargs: dict, device: str, num_envs: int, steps: int, updates: int = 6000, seed: int = 0):
    """Plain behaviour cloning of the scripted baseline: an MLP (256, 256; tanh output) fitted by squared error to
    ``num_envs x steps`` of its transitions (observations normalised), as a policy factory for :func:`object_progress`.
    How much of the baseline a network recovers from that many demonstrations."""
    from magwarp.training import make_env
    from magwarp.training.common import RunningMeanStd, flatten_obs
    from magwarp.training.policy import mlp

    torch.manual_seed(seed)
    env, base = make_env(env_id, num_envs, device, seed, env_kwargs)
    teacher, scale = _scripted(base), torch.as_tensor(base.single_action_space.high, device=base.device)
    obs, _ = env.reset(seed=seed)
    xs, acts = [], []
    with torch.no_grad():
        for _ in range(steps):
            a = teacher(obs)
            xs.append(flatten_obs(obs))
            acts.append((a / scale).clamp(-1, 1))
            obs, *_ = env.step(a)
    env.close()
    x, a = torch.cat(xs), torch.cat(acts)
    rms = RunningMeanStd(x.shape[1], base.device, clip=5.0)
    rms.update(x)
    net = mlp(x.shape[1], [256, 256], a.shape[1], act=torch.nn.ReLU).to(base.device)
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    for _ in range(updates):
        idx = torch.randint(len(x), (256,), device=base.device)
        loss = (torch.tanh(net(rms.normalize(x[idx]))) - a[idx]).square().sum(-1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return lambda base: (lambda o: torch.tanh(net(rms.normalize(flatten_obs(o)))).detach() * scale)


def train(name: str, minutes: float | None, total_steps: int | None, device: str, num_envs: int, extra: list[str],
          out: str) -> dict:
    """Train paper run ``name`` (its env options, its script options, then ``extra``); returns the summary."""
    from magwarp.training import sac_her
    from magwarp.training.paper import PAPER_RUNS

    run = PAPER_RUNS[name]
    budget = ["--total-steps", str(total_steps)] if total_steps else ["--minutes", str(minutes)]
    argv = ["--env-id", run.env_id, "--env-kwargs", run.train_json(), "--eval-env-kwargs", run.eval_json(),
            "--device", device, "--num-envs", str(num_envs), "--out", out, "--no-progress", "--eval-steps", "0",
            "--eval-every", "0", *budget, *run.script_args, *extra]
    return sac_her.train(sac_her.parse_args(argv))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: cuda:0 when present, else cpu)")
    p.add_argument("--runs", default=",".join(DEFAULT_RUNS), help="paper runs to train (comma separated)")
    p.add_argument("--minutes", type=float, default=5.0, help="training budget of each run")
    p.add_argument("--num-envs", type=int, default=None, help="training worlds (default: the SAC preset's)")
    p.add_argument("--eval-envs", type=int, default=256, help="worlds (one episode each) per policy evaluated")
    p.add_argument("--args", default="", help="extra training options for every run")
    p.add_argument("--work", default=None, help="folder of the run folders (default: a temporary one)")
    p.add_argument("--smoke", action="store_true", help="CPU check: 8 worlds, tiny networks, 600 env steps per run")
    p.add_argument("--clone-steps", default="",
                   help="also clone the baseline from this many batched steps of it (comma separated: one row each)")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    info, devices = start_run(args.device)
    device = args.device or devices[-1]
    extra = shlex.split(args.args)
    total = None
    if args.smoke:
        device, total, args.eval_envs = "cpu", 600, 8
        args.num_envs = args.num_envs or 8
        extra = ["--batch-size", "64", "--updates-per-step", "2", "--hidden", "32,32", *extra]
    num_envs = args.num_envs or 4096
    from magwarp.training.paper import PAPER_RUNS

    names = [n.strip() for n in args.runs.split(",") if n.strip()]
    unknown = [n for n in names if n not in PAPER_RUNS]
    if unknown:
        raise SystemExit(f"unknown runs {unknown}; choose from {list(PAPER_RUNS)}")
    work = args.work or tempfile.mkdtemp(prefix="coop_learning_")
    first = names[0] if names else DEFAULT_RUNS[0]  # no run named: the reference rows (and clones) only
    ref = PAPER_RUNS[first]
    rows = []

    def measure(label: str, policy, env_kwargs: dict, **more) -> None:
        res = object_progress(ref.env_id, env_kwargs, policy, args.eval_envs, device, seed=77_000)
        rows.append({"policy": label, **res, **more})
        print(f"{label}: success {res['success_rate']:.3f}, object progress {res['object_progress_m']:+.4f} m, "
              f"collisions {res['collision_rate']:.3f}", flush=True)

    measure("zero", _zero, ref.eval_kwargs)
    measure("scripted", _scripted, ref.eval_kwargs)
    untrained = os.path.join(work, "untrained")  # one env step, no update: the initial actor's policy.pt
    train(first, None, num_envs, device, num_envs, [*extra, "--learning-starts", "10"], untrained)
    measure("untrained", _trained(os.path.join(untrained, "policy.pt")), ref.eval_kwargs)
    for steps in [int(v) for v in args.clone_steps.split(",") if v.strip()]:
        measure(f"cloned ({steps * (args.num_envs or 16)} transitions)",
                cloned(ref.env_id, ref.train_kwargs, device, args.num_envs or 16, steps), ref.eval_kwargs)
    for name in names:
        out = os.path.join(work, name)
        summary = train(name, args.minutes, total, device, num_envs, extra, out)
        run = PAPER_RUNS[name]
        trained = _trained(os.path.join(out, "policy.pt"))
        measure(name, trained, run.eval_kwargs, train_steps=summary["global_step"], train_s=summary["wall_s"],
                train_success=summary["success_rate"])
        if run.train_kwargs != run.eval_kwargs:  # e.g. lighter boxes in training: did it learn what it saw?
            measure(f"{name} (training options)", trained, run.train_kwargs)
    columns = ["policy", "success_rate", "object_progress_m", "collision_rate", "episodes", "start_distance_m",
               "train_steps", "train_s", "train_success"]
    return finish(rows, columns, info, args.json)


if __name__ == "__main__":
    sys.exit(main())
