"""Training: PPO (:mod:`magwarp.training.ppo`) and SAC + HER (:mod:`magwarp.training.sac_her`), one CleanRL-style
module each, run by ``magwarp train``, ``python -m magwarp.training.ppo`` or torchrun
(:mod:`magwarp.training.distributed`); the helpers they share (observation flattening and normalisation, success
tracking, CSV / TensorBoard logging with a PNG curve, checkpoints, time to target: :mod:`magwarp.training.loop`), the
policy file format (:mod:`magwarp.training.policy`) and the shipped policies (:func:`load_pretrained`).
"""

from magwarp.training.common import (OBS_KEYS, CsvLogger, RunningMeanStd, SuccessTracker, Timer, evaluate, flatten_obs,
                                     load_checkpoint, make_env, obs_dim, parse_env_kwargs, plot_curve, save_checkpoint,
                                     seed_everything)
from magwarp.training.policy import FlatPolicy, Policy, load_policy, mlp, save_policy
from magwarp.training.pretrained import load_pretrained, pretrained_names, pretrained_path

__all__ = ["OBS_KEYS", "CsvLogger", "RunningMeanStd", "SuccessTracker", "Timer", "evaluate", "flatten_obs",
           "load_checkpoint", "make_env", "obs_dim", "parse_env_kwargs", "plot_curve", "save_checkpoint",
           "seed_everything", "FlatPolicy", "Policy", "load_policy", "mlp", "save_policy", "load_pretrained",
           "pretrained_names", "pretrained_path"]
