"""Demonstrations from an env's scripted baseline for off-policy training (SAC + HER): acting with it for a while.

A task whose success needs behaviour that random exploration almost never shows (e.g. ``magwarp/CoopPush-v0``: two
movers lined up behind a box one of them cannot move) gives hindsight relabelling nothing to learn from: the object
never moves, so every relabelled goal is "leave it where it is". Transitions of the env's scripted baseline
(:func:`magwarp.evaluate.scripted_policy`, what ``magwarp eval --policy scripted`` runs) show the object moving to
goals. :class:`ScriptedDemos` mixes its actions into the batch the learner collects:

* ``episodes``: the first ``episodes x max_episode_steps`` batched steps of a session act with the baseline in every
  world (``episodes`` episodes per world where none ends early): the replay buffer starts with its transitions,
  which the learner trains on as usual (updates start after ``--learning-starts`` as always);
* ``share``: the first ``round(share x num_envs)`` worlds act with the baseline for the whole session, so a fixed
  share of every replayed minibatch is demonstration data (as RLPD mixes offline data into every batch); the
  learner's own success statistics then count the other worlds only.

The stored actions are the baseline's, divided by the action scale (the learner's [-1, 1] units), and the replay
buffer marks them as demonstrations; ``--demo-bc`` adds a Q-filtered behaviour-cloning term on them to the actor
loss (:meth:`magwarp.training.sac_her.SacLearner._bc_loss`). Nothing else changes: the same rewards, relabelling and
env; the policy is evaluated on its own.
"""

from __future__ import annotations

import torch

__all__ = ["ScriptedDemos"]


class ScriptedDemos:
    """Acts with ``base``'s scripted baseline in some worlds and steps (see the module docstring).

    ``base``: the unwrapped batched env; ``action_scale``: the action space's bound ``[A]`` (learner actions are in
    [-1, 1]); ``episodes``: episodes per world of demonstrations at the start of a session; ``share``: the share of
    worlds that act with the baseline throughout, in [0, 1), leaving at least one world to the learner."""

    def __init__(self, base, action_scale: torch.Tensor, episodes: int = 0, share: float = 0.0):
        from magwarp.evaluate import EvalError, scripted_policy

        if isinstance(episodes, bool) or int(episodes) != episodes or episodes < 0:
            raise ValueError(f"demo episodes must be a whole number >= 0, got {episodes!r}")
        share = float(share)
        if not 0.0 <= share < 1.0:
            raise ValueError(f"the demo share of worlds must lie in [0, 1), got {share!r}")
        self.num_envs = n = int(base.num_envs)
        self.worlds = int(round(share * n))  # the first `worlds` worlds act with the baseline throughout
        if self.worlds >= n:
            raise ValueError(f"a demo share of {share!r} of {n} worlds leaves none to the learner")
        length = getattr(base, "max_episode_steps", None)
        if episodes and length is None:
            raise ValueError(f"demo episodes need an env with max_episode_steps; {type(base).__name__} has none: "
                             "use the demo share instead")
        self.seed_steps = int(episodes) * int(length or 0)
        self.policy = None
        if self.enabled:
            try:
                self.policy = scripted_policy(base)
            except EvalError as e:
                raise ValueError(f"demonstrations need the env's scripted baseline: {e}") from None
        self.scale = action_scale
        self.mask = torch.zeros(n, dtype=torch.bool, device=action_scale.device)
        self.mask[: self.worlds] = True
        self._all = torch.ones_like(self.mask)

    @property
    def enabled(self) -> bool:
        return self.seed_steps > 0 or self.worlds > 0

    def share_at(self, env_steps: int) -> float:
        """The share of worlds that act with the baseline at the session's batched step ``env_steps``."""
        return 1.0 if env_steps < self.seed_steps else self.worlds / self.num_envs

    def acting(self, env_steps: int) -> torch.Tensor:
        """``[N]`` bool: the worlds that act with the baseline at the session's batched step ``env_steps``."""
        return self._all if env_steps < self.seed_steps else self.mask

    @torch.no_grad()
    def __call__(self, obs, action: torch.Tensor, env_steps: int) -> torch.Tensor:
        """``action`` ``[N, A]`` (learner units) with the baseline's actions in the worlds that act with it now."""
        if env_steps >= self.seed_steps and self.worlds == 0:
            return action
        demo = (self.policy(obs).reshape(action.shape) / self.scale).clamp(-1.0, 1.0)
        if env_steps < self.seed_steps:
            return demo
        return torch.where(self.mask[:, None], demo, action)

    def learner_rows(self, value):
        """The learner's worlds' rows of a per-world tensor (other values pass through): what its statistics count."""
        if self.worlds and isinstance(value, torch.Tensor) and value.dim() and value.shape[0] == self.num_envs:
            return value[self.worlds:]
        return value
