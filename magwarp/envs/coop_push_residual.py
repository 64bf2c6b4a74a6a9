"""Residual learning on the cooperative-push baseline: ``magwarp/CoopPushResidual-v0``.

:class:`~magwarp.envs.coop_push.CoopPushEnv` (every option the same) whose action is a correction to the scripted
baseline's (:class:`~magwarp.policies.coop_push.CoopPushPolicy`: line up behind the box, push together, settle; the
mechanism is :class:`~magwarp.envs.residual.ResidualAction`): the applied acceleration is ``scripted(obs) +
residual_scale * action`` (m/s^2), the action in the base env's range ``[-a_max, a_max]`` per component, so the
correction reaches ``residual_scale * a_max`` (5 m/s^2 by default). The sum is passed on unclipped, as in the base
env: the drive norm-clips every mover's command to ``a_max``. A zero action is the baseline exactly (its success,
73% in ``magwarp eval``), so a policy starts where the baseline is and learns what the shared reward asks beyond
it; ``magwarp eval magwarp/CoopPushResidual-v0 --policy scripted`` runs the zero correction. Observation, reward,
ends and ``info`` are the base env's.

Why: random actions never move a box that needs two movers, so learners from scratch see no reward (SAC+HER:
0% after 5 minutes on an H100, 0.26% with scripted demonstrations in its buffer; ``benchmarks/RESULTS.md``). What
the baseline leaves to learn: its failures are mostly time-outs on far goals (on 128 worlds: 23% failed, 2% by a
collision; every failed world had started pushing, from goals 0.41 m away on average against 0.29 m for the solved
ones, and ended a median 16 cm short). Its velocity loop is deadbeat over one held step, so a steady correction
``c`` shifts a mover's velocity by ``c dt`` (up to 0.2 m/s with the defaults; ``residual_scale=1`` doubles it). On
the CPU (64 worlds, ~75k env steps of PPO, 256 evaluation episodes against the baseline's 69%), half range ended at
67% with 3.5% collisions, full range at 64% with 5.1% (the baseline: 1.6%): the default keeps the smaller range.

Why an env and not only a policy: the baseline keeps state between steps (whether the movers have lined up and
push, and the push direction it holds near the goal) and reads the episode's step count, none of which the
observation holds; the env keeps that state per world and resets it with the episode. A stateless variant (pushing
whenever every mover is behind its slot, the direction near the goal from the movers through the object) solved 62%
of 205 episodes where the baseline solved 73% of 192 (64 worlds, 300 steps, CPU), so the state stays. For plain
``magwarp/CoopPush-v0``, :meth:`CoopPushResidualEnv.write_standalone_policy` packs a trained policy with the
baseline into one TorchScript file (:class:`~magwarp.policies.coop_push.CoopPushResidualPolicy`, which keeps the
baseline's state itself and starts a world afresh when its goal changes); PPO writes it beside ``policy.pt`` as
``policy_coop_push.pt``, and it steps CoopPush-v0 exactly as the policy steps this env.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

from magwarp.envs.coop_push import CoopPushConfig, CoopPushEnv
from magwarp.envs.residual import ResidualAction, check_residual_scale

__all__ = ["CoopPushResidualConfig", "CoopPushResidualEnv"]


@dataclass(frozen=True)
class CoopPushResidualConfig(CoopPushConfig):
    """Options of :class:`CoopPushResidualEnv`: :class:`~magwarp.envs.coop_push.CoopPushConfig`'s (acceleration
    control: ``learn_jerk`` stays False), and ``residual_scale``: the correction's range as a share of ``a_max`` (in
    (0, 2], default 0.5); ``baseline_options``: keyword options of :class:`~magwarp.policies.coop_push.CoopPushPolicy`
    (its speeds, spacing, ...; None: its defaults). The names are checked here, the values by the policy."""

    residual_scale: float = 0.5
    baseline_options: dict | None = None

    def __post_init__(self):
        check_residual_scale(self.residual_scale)
        opts = self.baseline_options
        if opts is not None:
            if not isinstance(opts, dict):
                raise TypeError(f"baseline_options must be a dict of CoopPushPolicy options, got {opts!r}")
            from magwarp.policies.coop_push import CoopPushPolicy

            known = [n for n, p in inspect.signature(CoopPushPolicy.__init__).parameters.items()
                     if n not in ("self", "env") and p.kind is not p.VAR_KEYWORD]
            unknown = sorted(str(k) for k in opts if k not in known)
            if unknown:
                raise TypeError(f"unknown baseline_options {unknown}; CoopPushPolicy takes {known}")
        super().__post_init__()
        if self.learn_jerk:
            raise ValueError("CoopPushResidualEnv corrects the baseline's accelerations (CoopPushPolicy commands "
                             "accelerations): learn_jerk must be False, got learn_jerk=True")


class CoopPushResidualEnv(ResidualAction, CoopPushEnv):
    """:class:`CoopPushEnv` whose action corrects the scripted baseline's (see the module docstring). Options:
    :class:`CoopPushResidualConfig` (``residual_scale``, ``baseline_options`` and every CoopPush option), as a
    config and/or keywords; both are checked before the env is built."""

    config_type = CoopPushResidualConfig

    def __init__(self, num_envs: int = 1, config: CoopPushResidualConfig | None = None, **kwargs):
        from magwarp.policies.coop_push import CoopPushPolicy

        # the base constructor's first reset runs before the baseline exists (its observation is not returned)
        super().__init__(num_envs, config, **kwargs)
        cfg = self.config
        self.baseline_options = dict(cfg.baseline_options or {})
        self._init_residual(CoopPushPolicy(self, **self.baseline_options), cfg.residual_scale)

    #: the file :meth:`write_standalone_policy` writes beside a training run's ``policy.pt``
    STANDALONE_POLICY = "policy_coop_push.pt"

    def write_standalone_policy(self, policy_path: str, out_path: str) -> None:
        """Write the policy file ``policy_path`` (trained on this env) as one for plain ``magwarp/CoopPush-v0``
        observations (:class:`~magwarp.policies.coop_push.CoopPushResidualPolicy`: this env's baseline, with its
        options, plus ``residual_scale`` times the policy). Its metadata is the policy's, with ``env_id``
        ``magwarp/CoopPush-v0``, the residual env's id and scale, and env options without the residual ones."""
        import copy
        import json
        import os
        import warnings

        import torch

        from magwarp.policies.coop_push import CoopPushResidualPolicy
        from magwarp.training.policy import load_policy, policy_metadata

        residual = load_policy(policy_path)
        meta = policy_metadata(policy_path)
        core = copy.deepcopy(self.baseline.core).cpu()
        core.pushing, core.dir = torch.zeros(0, dtype=torch.bool), torch.zeros(0, 2)  # sized by the first batch
        module = CoopPushResidualPolicy(core, residual, self.residual_scale, 4 if self.learn_pose else 2,
                                        int(residual.obs_dim), int(residual.action_dim))
        for key in ("env_kwargs", "eval_env_kwargs"):
            if meta.get(key):
                kwargs = json.loads(meta[key]) if isinstance(meta[key], str) else dict(meta[key])
                meta[key] = json.dumps({k: v for k, v in kwargs.items()
                                        if k not in ("residual_scale", "baseline_options")})
        meta.update(env_id=module.env_id, residual_env_id=meta.get("env_id"), residual_scale=self.residual_scale,
                    baseline_options=self.baseline_options)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            scripted = torch.jit.script(module.eval())
        tmp = f"{out_path}.tmp"
        torch.jit.save(scripted, tmp, _extra_files={"magwarp.json": json.dumps(meta, default=str)})
        os.replace(tmp, out_path)
