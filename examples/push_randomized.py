"""Randomized pushing: object sizes and masses, walls and sensor noise drawn per world, all in one batch.

Run: python examples/push_randomized.py [--num-envs 128] [--episodes 2] [--device cpu]

MagBotSim randomizes these by rebuilding its MuJoCo model at every reset, one env per process. Here every world of
the batch gets its own draw without a rebuild: object variants are swapped into per-world mujoco-warp model arrays
(``object_ranges``), PushWithObstacles' walls change per world (``obstacle_mode="random"``), and observations get
seeded Gaussian noise (``std_noise``, ``object_noise``). The scripted push heuristic (which plans with each
world's own object outline) runs on both envs, and the script prints its success rate by object size and by gap
width: the spread a randomized env shows and a fixed one hides.
"""

import argparse

import torch

from magwarp.envs.push import PushBoxEnv
from magwarp.envs.push_obstacles import PushWithObstaclesEnv
from magwarp.policies.push import PushHeuristic


def run_rounds(env, rounds: int) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """``rounds`` episodes in every world, each started by a reset: ``(success, object variant, wall half length)``
    per world and round. A world whose episode ends early (a collision) autoresets; its new episode is not counted."""
    policy = PushHeuristic(env)
    out = []
    for r in range(rounds):
        obs, _ = env.reset(seed=r)
        variant = env.object_variant.clone()
        wall = env.obstacle_boxes[:, 0, 3].clone() if env.obstacles else torch.zeros(env.num_envs, device=env.device)
        success = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
        running = torch.ones_like(success)
        for _ in range(env.max_episode_steps):
            obs, reward, terminated, truncated, info = env.step(policy(obs))
            success |= info["is_success"] & running
            running &= ~(terminated | truncated)
        out.append((success, variant, wall))
    return out


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--num-envs", type=int, default=128)
    p.add_argument("--episodes", type=int, default=2)
    p.add_argument("--device", default=None)
    args = p.parse_args()

    # Push-Box with the box's half width drawn from [3, 7] cm and its mass from [0.1, 0.5] kg, noisy sensors.
    box = PushBoxEnv(args.num_envs, device=args.device, seed=0, object_ranges={"width": (0.03, 0.07), "mass": (0.1, 0.5)},
                     object_variants=32, std_noise=1e-4, object_noise=1e-4)
    rows = run_rounds(box, args.episodes)
    width = torch.tensor([s.width for s in box.variants.specs], device=box.device)
    ok = torch.cat([r[0] for r in rows]).float()
    w = torch.cat([width[r[1].long()] for r in rows])
    print(f"Push-Box, {args.num_envs} worlds x {args.episodes} episodes, random box size and mass:")
    for lo, hi in ((0.03, 0.045), (0.045, 0.06), (0.06, 0.07)):
        sel = (w >= lo) & (w < hi + 1e-9)
        print(f"  half width {100 * lo:.1f}-{100 * hi:.1f} cm: success {100 * ok[sel].mean():5.1f}% of {int(sel.sum())}")

    # PushWithObstacles with walls of random length per world: the gap between them is 20 to 32 cm wide.
    walls = PushWithObstaclesEnv(args.num_envs, device=args.device, seed=0, obstacle_mode="random")
    rows = run_rounds(walls, args.episodes)
    ok = torch.cat([r[0] for r in rows]).float()
    gap = walls.layout_top - 4 * torch.cat([r[2] for r in rows])  # the layout's height minus both walls
    print(f"PushWithObstacles, random walls: success {100 * ok.mean():.1f}% overall")
    for lo, hi in ((0.20, 0.24), (0.24, 0.28), (0.28, 0.32)):
        sel = (gap >= lo) & (gap < hi)
        if sel.any():
            print(f"  gap {100 * lo:.0f}-{100 * hi:.0f} cm: success {100 * ok[sel].mean():5.1f}% of {int(sel.sum())}")


if __name__ == "__main__":
    main()
