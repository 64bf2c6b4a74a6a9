"""The paper's training runs, with the env options they were trained and evaluated with.

MagBotSim's published run parameters (``docs/parameters/*.yaml`` in its repository, cited by the paper for Tables
3-5) change the envs' defaults: the pushing agents act every 160 control cycles (Push-T: 80), so an episode lasts
4 s instead of 1-2 s; rewards are -50 for a collision, -1 per step and 0 at the goal; the mover is a 113 mm,
0.639 kg box (``mover_params``; the envs' default is 155 mm, 1.24 kg) and its collision shape is that square;
Push-Box and Push-T run on 3 x 3 tiles (PushWithObstacles' walls need its own 4 x 3); Push-T trains with a 0.95
coverage goal (here 0.8, below) and is evaluated at 0.7; PushWithObstacles trains with a wall curriculum (here
also random gaps, below) and is evaluated on the hard walls; trajectory planning acts every 120 cycles with 0.09 m
half-size collision boxes and a 113 mm, 0.63 kg mover. A policy is evaluated in the env it is compared in, so each
run records both option sets: ``magwarp eval`` applies a policy file's ``eval_env_kwargs`` unless ``--env-kwargs``
is given.
``benchmarks/RESULTS.md`` (Training) lists what each run reached.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

__all__ = ["PaperRun", "PAPER_RUNS"]

MOVER_113MM = [0.113 / 2, 0.113 / 2, 0.012 / 2]  # the published runs' mover: half sizes, as mover_params takes them
MOVER_BOX = {"collision_shape": "box", "collision_size": [0.113 / 2 + 1e-6, 0.113 / 2 + 1e-6],
             "mover_params": {"size": MOVER_113MM, "mass": 0.639}}
TILES_3X3 = {"layout": [[1, 1, 1], [1, 1, 1], [1, 1, 1]]}
PUSH_REWARDS = {"collision_penalty": -50.0, "per_step_penalty": -1.0, "object_at_goal_reward": 0.0}


@dataclass(frozen=True)
class PaperRun:
    """One training run: env id, algorithm (:attr:`module`), env options for training and for the
    evaluation, the paper's table row it is compared with, and options of the training script (e.g. a seed)."""

    env_id: str
    algo: str
    train_kwargs: dict = field(default_factory=dict)
    eval_kwargs: dict = field(default_factory=dict)
    paper: str = ""
    script_args: tuple[str, ...] = ()

    @property
    def module(self) -> str:
        """The training module (``python -m`` it)."""
        return {"ppo": "magwarp.training.ppo", "sac-her": "magwarp.training.sac_her"}[self.algo]

    def train_json(self) -> str:
        return json.dumps(self.train_kwargs, separators=(",", ":"))

    def eval_json(self) -> str:
        return json.dumps(self.eval_kwargs, separators=(",", ":"))


_PUSHBOX = {"num_cycles": 160, **TILES_3X3, **MOVER_BOX, **PUSH_REWARDS}
_PUSHT = {"num_cycles": 80, **TILES_3X3, **MOVER_BOX, **PUSH_REWARDS}
# MagBotSim raises the walls every 800 episodes of each of its 50 envs (40,000 episodes, 1 M env steps per level);
# 10 episodes of each of the 4096 training worlds keep that schedule in env steps.
_OBSTACLES = {"num_cycles": 160, **MOVER_BOX}
_OBSTACLES_FINE = {"num_cycles": 40, **MOVER_BOX}
_B0 = {"num_cycles": 120, "collision_shape": "box", "collision_size": [0.09, 0.09]}
# the whole published trajectory-planning file (trajectory_planning_sac_nMovers_3.yaml): _B0 and its 113 mm, 0.63 kg
# mover (rounds 1-5 moved the envs' default 155 mm, 1.24 kg body)
_B0_PUBLISHED = {**_B0, "mover_params": {"size": MOVER_113MM, "mass": 0.63}}
_B0_FINE = {**_B0_PUBLISHED, "num_cycles": 40}
_B0_STARTS40 = {**_B0_PUBLISHED, "max_episode_steps": 40}  # training episodes cut after 40 steps (4.8 s)
# the residual swarm runs on 1,024 movers per world with the correction gated off slow movers (issue 18)
_SWARM_1024_GATE = {"num_movers": 1024, "planner": {"traffic": "lanes"}, "reward_progress": 5.0, "gate_speed": 0.3}
_PLATFORM_POSE = {"action_mode": "pose", "num_cycles": 40}
#: Issue 24's sim2real conditions (``benchmarks/robustness.py``'s "randomised"): the planar "sim2real" preset (its
#: ranges and where they come from: :data:`magwarp.envs.randomization.PRESETS`), an action latency of 0..5 control
#: cycles of 1 ms per world (the PLC task's output to the drive over EtherCAT: a few cycles), and sensor errors
#: larger than a planar motor's position feedback (tens of micrometres): a bias of std 1 mm and 10 mm/s per episode,
#: white noise of 0.5 mm and 5 mm/s per reading. No dropped readings: XPlanar reports the mover positions every 1 ms
#: cycle, so a lost frame leaves the PLC a reading 1 ms old, while the env's dropout repeats the reading of the
#: previous env step (120 ms on B0); robustness.py's ``dropout`` condition shows that stress on its own.
SIM2REAL = {"randomization": "sim2real", "actuation": {"latency_range": [0, 5]},
             "sensors": {"pos_bias_std": 0.001, "vel_bias_std": 0.01, "pos_noise_std": 0.0005, "vel_noise_std": 0.005}}
_COOP = {"num_cycles": 40}
_COOP_MASS_MIX = {"field": "object_mass", "dist": {"uniform": [0.3, 3.16]}, "op": "set", "mode": "reset"}
_LEV_SOFT = {"pd_frequency": 8.0, "pd_max_acc": [7.0, 120.0], "residual_scale": 0.05, "failure_reward": -50.0}
_B0_PAPER = "99.3% success, 2.14 collisions per 1000 goals (Table 5, simulation; SAC+HER)"


def _b0(algo: str, train_kwargs: dict, eval_kwargs: dict, script_args: tuple[str, ...] = ()) -> PaperRun:
    """A trajectory-planning B0 run, compared with the paper's simulation row."""
    return PaperRun("magwarp/TrajectoryPlanningB0-v0", algo, train_kwargs, eval_kwargs, _B0_PAPER, script_args)


PAPER_RUNS: dict[str, PaperRun] = {
    "b0_ppo": _b0("ppo", _B0_PUBLISHED, _B0_PUBLISHED),
    # the paper's own algorithm on its published options: 1.34 collisions per 1000 goals but 97.97% success, its
    # deterministic actions stopping movers short of their goals until the world times out (RESULTS)
    "b0_sac": _b0("sac-her", _B0_PUBLISHED, _B0_PUBLISHED),
    # the published mover and boxes with the envs' default 40-cycle (25 Hz) actions, finer control than the paper's
    # 120 cycles: PPO collided 3.82 times per 1000 goals, SAC+HER had not converged (RESULTS)
    "b0_ppo_fine": _b0("ppo", _B0_FINE, _B0_FINE),
    "b0_sac_fine": _b0("sac-her", _B0_FINE, _B0_FINE),
    # PPO's collisions come from episode starts: the evaluation begins a fresh 10 s run per world, and b0_ppo (one
    # start per ~1450 training steps) collided in 4.9% of its first three steps after a start and in 0.006% of the
    # steps after 100 (RESULTS). These cut every training episode after the evaluation's 10 s (83 steps of 120 cycles;
    # 250 of 40), or after 4.8 s (40 steps), so starts are seen often. b0_ppo_starts40 is pretrained:b0_ppo: 99.80%
    # success, 0.69 collisions per 1000 goals (83 steps: 1.83; 40-cycle actions: 3.04)
    "b0_ppo_starts": _b0("ppo", {**_B0_PUBLISHED, "max_episode_steps": 83}, _B0_PUBLISHED),
    "b0_ppo_starts40": _b0("ppo", _B0_STARTS40, _B0_PUBLISHED),
    # b0_ppo_starts40 again with other seeds (the run above has seed 0): how far one run is from the next
    **{f"b0_ppo_starts40_seed{seed}": _b0("ppo", _B0_STARTS40, _B0_PUBLISHED, ("--seed", str(seed)))
       for seed in (1, 2)},
    "b0_ppo_fine_starts": _b0("ppo", {**_B0_FINE, "max_episode_steps": 250}, _B0_FINE),
    "pushbox_sac": PaperRun("magwarp/PushBox-v0", "sac-her", _PUSHBOX, _PUSHBOX, "99.56% (Table 3)"),
    # trained at 0.8 coverage, not the paper's 0.95: near misses count as reached, a denser signal for a 15-minute
    # run; evaluated at the paper's 0.7
    "pusht_sac": PaperRun("magwarp/PushT-v0", "sac-her", {**_PUSHT, "min_coverage": 0.8},
                          {**_PUSHT, "min_coverage": 0.7}, "73.13% (Table 3)"),
    "obstacles_sac": PaperRun("magwarp/PushWithObstacles-v0", "sac-her",
                              {**_OBSTACLES, "obstacle_mode": "curriculum", "curriculum_episodes": 10},
                              {**_OBSTACLES, "obstacle_mode": "hard"}, "91.26% (Table 3)"),
    # the paper's options, with each world held at a wall level until it succeeds in half its episodes there
    # (an untrained policy crashes within a few steps, so the fixed schedule reaches the hard walls untrained)
    "obstacles_sac_gated": PaperRun("magwarp/PushWithObstacles-v0", "sac-her",
                                    {**_OBSTACLES, "obstacle_mode": "curriculum", "curriculum_episodes": 20,
                                     "curriculum_success_rate": 0.5},
                                    {**_OBSTACLES, "obstacle_mode": "hard"}, "91.26% (Table 3)"),
    # the same gate over a 5-episode window: round 1's 20-episode window held the simple walls until 2.5 M steps,
    # where the policy already succeeded in 65% of its episodes, and left too little of the run for the hard walls
    "obstacles_sac_gate5": PaperRun("magwarp/PushWithObstacles-v0", "sac-her",
                                    {**_OBSTACLES, "obstacle_mode": "curriculum", "curriculum_episodes": 5,
                                     "curriculum_success_rate": 0.5},
                                    {**_OBSTACLES, "obstacle_mode": "hard"}, "91.26% (Table 3)"),
    # walls of a random gap in every episode (MagBotSim's "random" mode, between the simple and the hard walls): the
    # curricula above lost all success once the walls narrowed; a mix keeps easier gaps in every batch. Give it the
    # whole 15 minutes: the learning rate falls to 0 over --minutes
    "obstacles_sac_random": PaperRun("magwarp/PushWithObstacles-v0", "sac-her",
                                     {**_OBSTACLES, "obstacle_mode": "random"},
                                     {**_OBSTACLES, "obstacle_mode": "hard"}, "91.26% (Table 3)"),
    # half the episodes on the hard walls it is evaluated on, half on random gaps (the hard end of a uniform draw is
    # rare in a batch): it learned more slowly than random gaps alone, 87.5% on the hard walls against 96.9% (RESULTS)
    "obstacles_sac_mix": PaperRun("magwarp/PushWithObstacles-v0", "sac-her",
                                  {**_OBSTACLES, "obstacle_mode": {"random": 0.5, "hard": 0.5}},
                                  {**_OBSTACLES, "obstacle_mode": "hard"}, "91.26% (Table 3)"),
    # MagBotSim's own 40-cycle control (25 Hz): with 160-cycle holds every exploratory episode crashes (even at a
    # quarter of the acceleration) and the 160-cycle run learned to stand still; at 40 cycles it still did (RESULTS)
    "obstacles_sac_fine": PaperRun("magwarp/PushWithObstacles-v0", "sac-her",
                                   {**_OBSTACLES_FINE, "obstacle_mode": "curriculum", "curriculum_episodes": 25},
                                   {**_OBSTACLES_FINE, "obstacle_mode": "hard"}, "91.26% (Table 3)"),
    # B0 at 40 cycles, trained with 1 cm larger safety boxes than it is evaluated with (0.10 vs 0.09 m): the policy
    # keeps a margin, for the collision target (the 120-cycle run collided 5.1 times per 1000 goals)
    "b0_ppo_margin": _b0("ppo", {**_B0, "num_cycles": 40, "collision_size": [0.1, 0.1]}, {**_B0, "num_cycles": 40}),
    # the same B0 run with a collision penalty 2.5x the paper's: a cautious policy, for the collision target
    "b0_ppo_cautious": _b0("ppo", {**_B0, "reward_collision": -50.0}, _B0),
    # MagBots (issue 19; the paper's future work, so no table row): 6-DoF platform poses through pose increments
    # (the IK maps them to the movers), and two movers pushing a box one cannot move
    "platform_pose_sac": PaperRun("magwarp/PlatformPose-v0", "sac-her", _PLATFORM_POSE, _PLATFORM_POSE,
                                  "no paper row; scripted IK baseline in magwarp eval"),
    # B0 under the "sim2real" randomisation, action latency (0-5 cycles) and sensor models (issue 24): from scratch,
    # and the shipped policy fine-tuned (a fresh critic trained alone for 10 iterations, then a fine-tuning rate)
    "b0_ppo_dr": _b0("ppo", {**_B0_STARTS40, **SIM2REAL}, {**_B0_PUBLISHED, **SIM2REAL}),
    "b0_ppo_dr_ft": _b0("ppo", {**_B0_STARTS40, **SIM2REAL}, {**_B0_PUBLISHED, **SIM2REAL},
                        ("--init-policy", "pretrained:b0_ppo", "--init-log-std", "-2.5", "--critic-warmup", "10",
                         "--lr", "1e-5")),
    # Swarms (issue 18; no paper row): parameter-shared PPO on the flat agent view of 256 worlds x 64 movers, evaluated
    # zero-shot on larger swarms beside the scripted planner (benchmarks/swarm.py)
    "swarm_ippo": PaperRun("magwarp/Swarm-v0", "ppo", {"num_movers": 64}, {"num_movers": 64},
                           "no paper row; scripted planner in magwarp eval", ("--num-envs", "256")),
    # swarm_ippo from scratch loses badly to the scripted planner (lanes + ORCA + safety filter: 96.5% of first goals
    # in 40 s at 1024 movers, no collision). Here PPO learns a per-mover correction on top of the planner
    # (magwarp/SwarmResidual-v0: planner + 0.5 x action, through the env's shield, so no correction can collide; the
    # PPO preset starts the actor at zero, i.e. at the planner's numbers) on 64 movers per world, to be evaluated
    # zero-shot on 256-4096 (examples/swarm_scaling.py --policy). Transfer: the planner's traffic="auto" takes its
    # one-way lanes only from 32 tiles a side, so 64 movers at 0.25 per tile (16 x 16 tiles) would train on straight
    # paths and run on lanes from 256 movers up; training forces the lanes, so the correction is learned on the
    # planner it corrects at scale (on 16 x 16 the lanes stay collision-free without deadlocks, at ~15% less
    # throughput than straight paths: 64 movers, 3 seeds x 4 worlds, 10 s, CPU). A residual may still learn to cut
    # the lanes' corners where, as here, the crowd is small; scale tests show whether that costs at 1024. Evaluated
    # with the planner's defaults (auto: straight paths at 64 movers, lanes from 256), the planner row's planner.
    # Dense progress reward 5 per metre: under the planner (64 movers, lanes) it is -0.93 +- 0.10 a step between
    # goals against the goal's +20 (a goal every ~6 s per mover, further than gamma 0.98 sees). Result (CPU, 25 min,
    # 9.6 M agent-steps, benchmarks/swarm_study.py): +12% over the planner at 256 movers for 20 s, but it jams the
    # crowd over time (80 s: 0.86x at 256, 0.43x at 1024 with 807 movers deadlocked; RESULTS.md): not shipped. With
    # residual_scale 0.25 and gamma 0.995 (CPU, 22 min): 0.97x at 256, 0.61x at 1024 (690 deadlocked)
    "swarm_residual": PaperRun("magwarp/SwarmResidual-v0", "ppo",
                               {"num_movers": 64, "planner": {"traffic": "lanes"}, "reward_progress": 5.0},
                               {"num_movers": 64}, "no paper row; the scripted planner (the zero correction)",
                               ("--num-envs", "256")),
    # The same residual trained where it is used: the 64-mover policies jam 1,024 movers (RESULTS.md), so these
    # train on 256 movers per world (32 x 32 tiles, the smallest the planner's auto traffic puts on lanes)
    # and on 1,024 (64 x 64): as many agents per step as swarm_residual (64 x 256, 16 x 1,024), on a GPU
    "swarm_residual_256": PaperRun("magwarp/SwarmResidual-v0", "ppo",
                                   {"num_movers": 256, "planner": {"traffic": "lanes"}, "reward_progress": 5.0},
                                   {"num_movers": 256}, "no paper row; the scripted planner (the zero correction)",
                                   ("--num-envs", "64")),
    "swarm_residual_1024": PaperRun("magwarp/SwarmResidual-v0", "ppo",
                                    {"num_movers": 1024, "planner": {"traffic": "lanes"}, "reward_progress": 5.0},
                                    {"num_movers": 1024}, "no paper row; the scripted planner (the zero correction)",
                                    ("--num-envs", "16")),
    # The runs above lower the training world's goal rate as they learn (GPU, 3 min: 256 movers 4.14 -> 2.16 goals
    # per 1000 agent-steps, 1,024 movers 2.19 -> 0.77; CPU, 25 min at 1,024: 2.58 -> 0.12). Half of each mover's
    # reward its world's mean (reward_team 0.5) alone did not stop that (CPU, 8 min at 256: 4.27 -> 2.80); here with a
    # longer horizon (gamma 0.995: ~8 s; the jams build over tens of seconds) and Monte-Carlo advantages (GAE lambda 1,
    # which stopped the levitation residual's drift)
    "swarm_residual_256_team": PaperRun("magwarp/SwarmResidual-v0", "ppo",
                                        {"num_movers": 256, "planner": {"traffic": "lanes"}, "reward_progress": 5.0,
                                         "reward_team": 0.5},
                                        {"num_movers": 256}, "no paper row; the scripted planner (the zero correction)",
                                        ("--num-envs", "64", "--gamma", "0.995", "--gae-lambda", "1.0")),
    # swarm_residual_256 with the correction gated (gate_speed 0.3 m/s: none for slow movers and the planner's
    # deadlock escapes), in training and in evaluation
    "swarm_residual_256_gate": PaperRun("magwarp/SwarmResidual-v0", "ppo",
                                        {"num_movers": 256, "planner": {"traffic": "lanes"}, "reward_progress": 5.0,
                                         "gate_speed": 0.3},
                                        {"num_movers": 256, "gate_speed": 0.3},
                                        "no paper row; the scripted planner (the zero correction)",
                                        ("--num-envs", "64")),
    # the same gate, trained on 1,024 movers per world (64 x 64 tiles), where the 256-mover gated policy gives 0.93x.
    # CPU, 25 min, one world (--num-envs 1), 10 M agent-steps: 1.001x / 1.012x / 1.102x the planner's goals at 1,024
    # movers over 80 s, seeds 0 / 1 / 2, no collisions, but 0.79x over 400 s (RESULTS.md)
    "swarm_residual_1024_gate": PaperRun("magwarp/SwarmResidual-v0", "ppo", _SWARM_1024_GATE,
                                         {"num_movers": 1024, "gate_speed": 0.3},
                                         "no paper row; the scripted planner (the zero correction)",
                                         ("--num-envs", "16")),
    # the same, its training worlds cut every 80 s (max_episode_steps 2000, the evaluation's horizon): a world that
    # runs on jams as it ages (benchmarks/swarm_jam.py), so the uncut run learns mostly in jammed worlds. CPU, 25 min,
    # 7.9 M agent-steps: 1.072x / 1.061x / 1.036x the planner over 80 s at 1,024 movers, seeds 0-2, and 1.255x /
    # 0.878x / 1.149x over 400 s, no collisions (RESULTS.md); shipped as pretrained:swarm_residual_1024_gate_ep. At
    # main on 2026-12-08 (the planner's kernels; a 400-s world's total is chaotic): 1.062x over 80 s (seeds 0-2) and
    # 0.868x over 400 s (seeds 0-5); the same recipe trained again there (7.86 M agent-steps): 1.036x and 0.894x
    # (seeds 0-2), not shipped
    "swarm_residual_1024_gate_ep": PaperRun("magwarp/SwarmResidual-v0", "ppo",
                                            {**_SWARM_1024_GATE, "max_episode_steps": 2000},
                                            {"num_movers": 1024, "gate_speed": 0.3},
                                            "no paper row; the scripted planner (the zero correction)",
                                            ("--num-envs", "16")),
    # swarm_residual_1024_gate_ep fine-tuned in worlds that run for 400 s (max_episode_steps 10000): the shipped
    # policy falls behind the planner on one seed of three over 400 s as its world ages (RESULTS.md); with the planner
    # as Warp kernels the CPU's residual env steps about 4.5x faster, so one world lives through 400-s episodes within
    # a run of 25 minutes. CPU, 25 min, 17.2 M agent-steps: worse over 400 s than the shipped policy (0.91x / 0.74x
    # the planner's goals on seeds 0 / 1, against 1.02x / 0.79x; RESULTS.md); not shipped
    "swarm_residual_1024_gate_long": PaperRun("magwarp/SwarmResidual-v0", "ppo",
                                              {**_SWARM_1024_GATE, "max_episode_steps": 10000},
                                              {"num_movers": 1024, "gate_speed": 0.3},
                                              "no paper row; the scripted planner (the zero correction)",
                                              ("--num-envs", "16", "--init-policy",
                                               "pretrained:swarm_residual_1024_gate_ep", "--critic-warmup", "10",
                                               "--lr", "3e-5")),
    # swarm_residual_1024_gate_ep trained on (from the shipped policy, a fresh critic) in the same 80-s worlds, with the
    # planner's kernels: 25 more minutes on the CPU, 17.9 M agent-steps more. Worse: 0.90x / 1.00x / 0.95x the
    # planner's goals over 80 s (seeds 0-2; the shipped policy 1.02x / 1.08x / 1.03x) and 0.54x over 400 s on seed 1
    # (RESULTS.md); not shipped
    "swarm_residual_1024_gate_ep2": PaperRun("magwarp/SwarmResidual-v0", "ppo",
                                             {**_SWARM_1024_GATE, "max_episode_steps": 2000},
                                             {"num_movers": 1024, "gate_speed": 0.3},
                                             "no paper row; the scripted planner (the zero correction)",
                                             ("--num-envs", "16", "--init-policy",
                                              "pretrained:swarm_residual_1024_gate_ep", "--critic-warmup", "10")),
    # Levitation (issue 17; no paper row): a residual on the PD + commutation baseline (a zero action is the PD),
    # compared with the PD on energy at equal tracking error by benchmarks/levitation_policy.py
    "lev_residual": PaperRun("magwarp/LevitationResidual-v0", "ppo", {"failure_reward": -1000.0},
                             {"failure_reward": -1000.0}, "no paper row; the PD baseline", ("--eval-steps", "0")),
    # lev_residual does not beat the PD (41.5 J vs 37.8 J, 2.19 vs 2.11 mm, RESULTS): its residual learned a steady
    # upward force (CPU, 0.6 M steps: +0.63 of the z action, 0.8 mm above the setpoint; a constant such bias lowers the
    # return, so a biased gradient, not the reward: GAE at lambda 0.95 carries the critic's slope, while a 1 ms
    # action's true effect on the return is tiny). Here: GAE lambda 1 over 128-step rollouts (Monte-Carlo advantages;
    # the bias stayed under 0.05), a residual of 0.05 (2 N, 0.1 N m) over a retuned PD, 8 Hz with acceleration limits
    # 7 m/s^2 and 120 rad/s^2 (the shipped PD clips at 5 and 60, which sets its tracking: this base alone spends ~3%
    # less than the 15 Hz PD and tracks 2-5% better; benchmarks/levitation_policy.py prints it beside the policy),
    # failures at -50 (about the discounted cost of flying on; -1000 and -100 pay for flying high, away from the few
    # falls near the tile seams). CPU, 1.5 M steps on 128 worlds, evaluated on 256: 39.38 J, 2.064 mm, 12.92 mrad vs
    # the shipped PD's 40.41 J, 2.113 mm, 13.39 mrad (its base alone: 39.33 J): the residual keeps, not adds, the gain
    "lev_residual_soft": PaperRun("magwarp/LevitationResidual-v0", "ppo", _LEV_SOFT, _LEV_SOFT,
                                  "no paper row; the PD baseline",
                                  ("--eval-steps", "0", "--gae-lambda", "1.0", "--num-steps", "128")),
    "coop_push_sac": PaperRun("magwarp/CoopPush-v0", "sac-her", {"num_cycles": 40}, {"num_cycles": 40},
                              "no paper row; scripted line-up-and-push baseline in magwarp eval"),
    # coop_push_sac stayed at 0% (5 minutes, H100): random actions never move a box that needs two movers, so every
    # hindsight goal is "leave it where it is". Here the scripted baseline acts in every world for the first episode
    # and in a quarter of the worlds throughout (magwarp.training.demos): the buffer holds pushes to goals. Same task,
    # same evaluation (the policy acts alone)
    "coop_push_sac_demos": PaperRun("magwarp/CoopPush-v0", "sac-her", {"num_cycles": 40}, {"num_cycles": 40},
                                    "no paper row; scripted line-up-and-push baseline in magwarp eval",
                                    ("--demo-episodes", "1", "--demo-share", "0.25")),
    # the same demonstrations, and the actor also clones them where its critic rates them above its own action
    # (Q-filtered behaviour cloning, as DDPG + HER with demonstrations in Nair et al. 2018). Weight 5: about the size
    # of the critic's pull (|Q| reaches ~15). Plain cloning of the baseline needs data: an MLP fitted to 4,800 of its
    # transitions moved the box 1.9 cm away from its goals, to 24,000 of them 3.7 cm nearer (CPU); this run sees ~1 M
    "coop_push_sac_demos_bc": PaperRun("magwarp/CoopPush-v0", "sac-her", {"num_cycles": 40}, {"num_cycles": 40},
                                       "no paper row; scripted line-up-and-push baseline in magwarp eval",
                                       ("--demo-episodes", "1", "--demo-share", "0.25", "--demo-bc", "5.0")),
    # no demonstrations: each training episode draws the box's mass from 0.3 kg (Push-Box's) to the task's 3.16 kg
    # (the object_mass randomisation term, per world at every reset); below 2.1 kg one mover moves it, so random
    # exploration moves it in most episodes. Evaluated on the task's box alone
    "coop_push_sac_mass_mix": PaperRun("magwarp/CoopPush-v0", "sac-her", {**_COOP, "randomization": [_COOP_MASS_MIX]},
                                       _COOP, "no paper row; scripted line-up-and-push baseline in magwarp eval"),
    # PPO on a residual over the scripted baseline (magwarp/CoopPushResidual-v0: the applied acceleration is the
    # baseline's plus a learned correction of up to 5 m/s^2; the actor starts at zero, the baseline's 73%): the
    # policy file acts on the residual env, which runs the baseline (it keeps state the observation does not hold).
    # PPO's "CoopPushResidual" preset (ppo.PRESETS) sets the rest; the suite's "scripted" row is the zero correction.
    # The run also writes policy_coop_push.pt, the same policy for plain CoopPush-v0 (what ships). On the CPU (64
    # worlds, 6 minutes, 92k env steps) it ended at 64.8% against the baseline's 69.1% on the same 256 episodes
    # (collisions 4.3% against 1.6%; a collision penalty of -50 instead of -10: the same): too few steps to learn
    "coop_push_residual": PaperRun("magwarp/CoopPushResidual-v0", "ppo", _COOP, _COOP,
                                   "no paper row; scripted line-up-and-push baseline (the zero correction)"),
}
