"""Shared by the MagBot tests: step a mujoco-warp backend and compare it with float64 MuJoCo C."""

from __future__ import annotations

import numpy as np
import torch

from magwarp.physics import MjwBackend, oracle


def load_magbots_benchmark():
    """benchmarks/magbots.py as a module (benchmarks/ is no package)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "benchmarks" / "magbots.py"
    spec = importlib.util.spec_from_file_location("bench_magbots", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def rollout_vs_mujoco_c(b: MjwBackend, xml: str, acts: np.ndarray) -> tuple[np.ndarray, list[float]]:
    """Step ``b`` through ``acts`` ``[steps, W, M, d]`` from its reset state; return qpos after every step
    ``[steps, W, nq]`` and, per world, the largest |qpos - MuJoCo C| of the same actions from the same start."""
    got = []
    for a in acts:
        b.step(torch.as_tensor(a, dtype=torch.float32))
        got.append(b.qpos_t.numpy().copy())
    got = np.array(got)
    errors = []
    for w in range(acts.shape[1]):
        want, _ = oracle.rollout(xml, acts[:, w], b.control, init_qpos=b.init_qpos.numpy()[w].astype(np.float64))
        errors.append(float(np.abs(got[:, w] - want).max()))
    return got, errors
