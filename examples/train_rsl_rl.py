"""Train trajectory planning (B0) with rsl_rl's ``OnPolicyRunner`` (Isaac Lab's and mjlab's PPO) on a magwarp env.

The env goes to rsl_rl through :class:`magwarp.envs.adapters.RslRlVecEnv`; the runner, the PPO algorithm and the
models are rsl_rl's own, configured as an Isaac Lab ``train_cfg`` dict. At the end the deterministic policy runs for
``--eval-steps`` steps and the success rate (goals reached / goals reached or lost) is printed.

    pip install -e ".[rsl_rl]"
    python examples/train_rsl_rl.py --device cuda --num-envs 4096 --iterations 300
    python examples/train_rsl_rl.py --device cpu --num-envs 64 --iterations 5 --steps-per-env 8   # a quick CPU check

Writes TensorBoard logs and ``model_<it>.pt`` checkpoints (rsl_rl's format) under ``--log-dir``, and ``policy.pt``:
rsl_rl's TorchScript export of the deterministic actor (observation normaliser included) with its output scaled to
the env's units, so that ``magwarp eval magwarp/TrajectoryPlanningB0-v0 --policy <log-dir>/policy.pt`` evaluates it
(its input is the flat observation of the adapter's ``"policy"`` group, the layout ``magwarp eval`` feeds).
"""

from __future__ import annotations

import argparse
import os

import torch
from torch import nn

from magwarp.envs.adapters import RslRlVecEnv
from magwarp.evaluate import load_policy
from magwarp.training import evaluate, seed_everything


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env-id", default="magwarp/TrajectoryPlanningB0-v0")
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--num-envs", type=int, default=4096)
    p.add_argument("--iterations", type=int, default=300, help="OnPolicyRunner learning iterations")
    p.add_argument("--steps-per-env", type=int, default=24, help="rollout length per env and iteration")
    p.add_argument("--max-episode-steps", type=int, default=200,
                   help="episode-length cut (episode starts are seen often; random initial lengths desync the cuts)")
    p.add_argument("--hidden", default="256,256,128", help="actor and critic hidden layer sizes")
    p.add_argument("--lr", type=float, default=1e-3, help="initial learning rate (adapted to a KL target of 0.01)")
    p.add_argument("--eval-steps", type=int, default=250, help="deterministic evaluation steps after training")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--log-dir", default="runs/b0_rsl_rl")
    return p.parse_args(argv)


def train_cfg(args: argparse.Namespace) -> dict:
    """An Isaac Lab-style rsl_rl 5.x configuration (PPO, MLP actor and critic with observation normalisation)."""
    mlp = {"class_name": "MLPModel", "hidden_dims": [int(h) for h in args.hidden.split(",")], "activation": "elu",
           "obs_normalization": True}
    return {
        "num_steps_per_env": args.steps_per_env,
        "save_interval": 100,
        "obs_groups": {"actor": ["policy"], "critic": ["policy"]},
        "algorithm": {"class_name": "PPO", "num_learning_epochs": 5, "num_mini_batches": 4, "learning_rate": args.lr,
                      "schedule": "adaptive", "desired_kl": 0.01, "gamma": 0.99, "lam": 0.95, "entropy_coef": 0.005,
                      "clip_param": 0.2, "max_grad_norm": 1.0},
        "actor": {**mlp, "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": 0.5}},
        "critic": mlp,
    }


class EnvUnitsPolicy(nn.Module):
    """rsl_rl's exported actor (flat observation in, policy action out) with its actions scaled to the env's units."""

    def __init__(self, actor: nn.Module, action_scale: torch.Tensor):
        super().__init__()
        self.actor = actor
        self.register_buffer("action_scale", action_scale)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.actor(obs) * self.action_scale


def main(argv=None) -> dict[str, float]:
    from rsl_rl.runners import OnPolicyRunner

    args = parse_args(argv)
    seed_everything(args.seed)
    env = RslRlVecEnv(args.env_id, num_envs=args.num_envs, device=args.device, seed=args.seed,
                      max_episode_steps=args.max_episode_steps, check_inputs=False)  # rsl_rl checks for NaNs
    runner = OnPolicyRunner(env, train_cfg(args), log_dir=args.log_dir, device=str(env.device))
    runner.learn(args.iterations, init_at_random_ep_len=True)
    path = os.path.join(args.log_dir, "policy.pt")
    actor = runner.alg.get_policy().as_jit().cpu()
    torch.jit.script(EnvUnitsPolicy(actor, env.action_scale.cpu())).save(path)

    policy = load_policy(path, env.env)  # what `magwarp eval --policy` loads
    stats = evaluate(env.env, policy, args.eval_steps)
    print(f"deterministic eval over {args.eval_steps} steps x {env.num_envs} envs: success rate "
          f"{stats['success_rate']:.4f}, collisions per episode {stats['collisions_per_episode']:.3f}, "
          f"{stats['episodes']:.0f} episodes\nmagwarp eval {args.env_id} --policy {path}")
    return stats


if __name__ == "__main__":
    main()
