"""Helpers shared by the training examples (``examples/train_ppo.py``, ``examples/train_sac_her.py``) and the
``magwarp train`` / ``magwarp export`` commands: observation flattening and normalisation, success tracking, CSV /
TensorBoard logging with a PNG curve, checkpoints, and the policy file format (:mod:`magwarp.training.policy`).
"""

from magwarp.training.common import (OBS_KEYS, CsvLogger, RunningMeanStd, SuccessTracker, Timer, evaluate, flatten_obs,
                                     load_checkpoint, make_env, obs_dim, parse_env_kwargs, plot_curve, save_checkpoint,
                                     seed_everything)
from magwarp.training.policy import FlatPolicy, Policy, load_policy, mlp, save_policy

__all__ = ["OBS_KEYS", "CsvLogger", "RunningMeanStd", "SuccessTracker", "Timer", "evaluate", "flatten_obs", "load_checkpoint",
           "make_env", "obs_dim", "parse_env_kwargs", "plot_curve", "save_checkpoint", "seed_everything", "FlatPolicy",
           "Policy", "load_policy", "mlp", "save_policy"]
