"""Scripted baseline policies (no learning): batched torch callables ``policy(obs) -> action``."""

from magwarp.policies.planner import GoalSeekingPlanner

__all__ = ["GoalSeekingPlanner"]
