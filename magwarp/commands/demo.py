"""``magwarp demo``: the point of the project in one command.

Runs the built-in collision-aware planner on a big batch of trajectory-planning worlds on the best device (GPU when
present, else CPU), prints the throughput next to MagBotSim's one-env-per-process rate, and writes a short video and
a PNG of a mosaic of worlds.

    magwarp demo                       # best device, default batch
    magwarp demo --device cpu --num-envs 1024 --steps 50 --out-dir demo_out
"""

from __future__ import annotations

import argparse
import os
import time

from magwarp.commands import UsageError

HELP = "run the built-in planner on a big batch on the best device; print throughput, write a video and a PNG"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("demo", help=HELP, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="magwarp/TrajectoryPlanningB0-v0", help="env id (default: the B0 benchmark)")
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: the best available)")
    p.add_argument("--num-envs", type=int, default=None, help="batch size (default: 65536 on GPU, 4096 on CPU)")
    p.add_argument("--steps", type=int, default=100, help="timed env steps (default 100; 1 step = 40 ms of motion)")
    p.add_argument("--video-steps", type=int, default=75, help="env steps in the video (default 75 = 3 s)")
    p.add_argument("--worlds-shown", type=int, default=16, help="worlds in the video mosaic (default 16)")
    p.add_argument("--out-dir", default="magwarp_demo", help="where to write demo.gif and demo.png")
    p.add_argument("--seed", type=int, default=0)
    return p


def run(args) -> int:
    if args.steps < 1 or args.video_steps < 0 or args.worlds_shown < 1:
        raise UsageError("--steps and --worlds-shown must be >= 1, --video-steps >= 0")
    import gymnasium as gym
    import torch
    import warp as wp
    from tqdm import tqdm

    import magwarp
    from magwarp.record import VideoRecorder
    from magwarp.render import save_png

    wp.config.quiet = True
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)  # Warp 1.19: no banner or module-load lines
    device = args.device or magwarp.default_device()
    num_envs = args.num_envs or (65536 if device.startswith("cuda") else 4096)
    if num_envs < 1:
        raise UsageError(f"--num-envs must be >= 1, got {num_envs}")
    print(f"magwarp demo: {args.env}, {num_envs} worlds on {device}")
    env = gym.make_vec(args.env, num_envs=num_envs, device=device, check_inputs=False)
    policy = env.scripted_policy()
    obs, _ = env.reset(seed=args.seed)
    for _ in range(3):  # compile, capture, warm up
        obs, *_ = env.step(policy(obs))
    goals = torch.zeros((), dtype=torch.int64, device=env.device)
    collisions = torch.zeros((), dtype=torch.int64, device=env.device)
    wp.synchronize_device(device)
    start = time.perf_counter()
    for _ in tqdm(range(args.steps), desc="simulating", unit="step", leave=False):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        goals += info["goals_reached"].sum()
        collisions += terminated.sum()
    wp.synchronize_device(device)
    elapsed = time.perf_counter() - start
    steps_per_s = num_envs * args.steps / elapsed
    sim_seconds = num_envs * args.steps * env.num_cycles * env.sim.model.limits.dt
    print(f"  {steps_per_s:,.0f} env-steps/s ({sim_seconds / elapsed:,.0f}x real time summed over worlds; "
          f"MagBotSim: ~80 env-steps/s, one env per process, see benchmarks/RESULTS.md)")
    print(f"  planner: {int(goals) / (num_envs * args.steps):.3f} goals per world-step, "
          f"{int(collisions) / max(int(goals), 1):.3f} collisions per goal")

    os.makedirs(args.out_dir, exist_ok=True)
    if args.video_steps:
        shown = min(args.worlds_shown, num_envs)
        env.unwrapped.render_mode = "rgb_array"
        env.set_render_worlds(shown)
        gif = os.path.join(args.out_dir, "demo.gif")
        frame = None
        with VideoRecorder(gif, fps=25) as rec:
            for _ in tqdm(range(args.video_steps), desc="recording", unit="frame", leave=False):
                obs, *_ = env.step(policy(obs))
                frame = env.render()
                rec.add(frame)
        png = save_png(os.path.join(args.out_dir, "demo.png"), frame)
        print(f"  wrote {gif} and {png} ({shown} worlds)")
    return 0
