"""ONNX export of a trained policy (what industrial runtimes load, e.g. Beckhoff TwinCAT's machine-learning runtime).

The ONNX graph is the policy's flat path: input ``obs`` ``float32 [batch, obs_dim]`` (the goal-dict observation
flattened in sorted key order ``achieved_goal, desired_goal, observation``), output ``action``
``float32 [batch, action_dim]`` in the env's units; observation normalisation, the squashing and the action scale
are inside. ``batch`` is dynamic. Needs the optional packages ``onnx`` (and ``onnxruntime`` for the check).

The check compares onnxruntime with torch in units of each action's range (``|onnxruntime - torch| / action
scale``): the two runtimes sum a layer's products in different orders, and float32 keeps about 7 digits, so a
256-wide policy whose actions reach 10 m/s^2 differs by a few 1e-5 m/s^2, a few 1e-6 of its range.
"""

from __future__ import annotations

import json
import os
import warnings

import numpy as np
import torch

from magwarp._checks import as_count

__all__ = ["TARGETS", "export_onnx", "check_onnx"]

#: export targets: ``onnx`` (the policy's flat path, dynamic batch), ``twincat`` and ``twincat-mlp``
#: (:mod:`magwarp.training.twincat`)
TARGETS = ("onnx", "twincat", "twincat-mlp")


def _flat_module(policy: torch.nn.Module, obs_dim: int | None) -> tuple[torch.nn.Module, int]:
    if getattr(policy, "stateful", False):
        raise ValueError("the policy keeps state between calls (e.g. a scripted baseline's phase, which an ONNX graph "
                         "cannot hold): export the residual policy file it was built from")
    flat = getattr(policy, "flat", policy)
    recorded = getattr(policy, "obs_dim", None)
    dim = obs_dim if obs_dim is not None else recorded
    if dim is None:
        raise ValueError("the policy does not record its observation size: pass obs_dim (--obs-dim)")
    dim = as_count(dim, "obs_dim (--obs-dim)")
    if recorded is not None and dim != int(recorded):
        raise ValueError(f"obs_dim (--obs-dim) is {dim}, but the policy takes observations of size {int(recorded)}")
    return flat, dim


def export_onnx(policy_path: str, out: str, *, opset: int = 17, obs_dim: int | None = None, check: bool = True,
                atol: float = 1e-5, trusted: bool = False, target: str = "onnx") -> dict:
    """Write ``policy_path`` (TorchScript policy, ``torch.save``d module or training folder) as ONNX to ``out``.

    Returns ``{"obs_dim", "action_dim", "max_diff", "max_abs_diff"}``: the largest difference as a fraction of the
    action range (checked against ``atol``) and in the env's units; both None without onnxruntime or ``check``.
    ``target="twincat"`` or ``"twincat-mlp"``: :func:`magwarp.training.twincat.export_twincat` (batch 1, checked
    operator set, metadata
    and ``OUT.json`` sidecar; it takes the observation size from the policy and its env, so ``obs_dim`` must be None).
    """
    if target not in TARGETS:
        raise ValueError(f"unknown export target {target!r}; choose one of {', '.join(TARGETS)}")
    if target != "onnx" and obs_dim is not None:
        raise ValueError("the twincat target takes the observation size from the policy and its env: drop obs_dim "
                         "(--obs-dim)")
    try:
        import onnx
    except ImportError:
        raise ImportError("ONNX export needs the optional packages onnx and onnxruntime: "
                          "pip install 'magwarp[onnx]' (or pip install onnx onnxruntime)") from None
    from magwarp.training.policy import load_policy

    if target != "onnx":
        from magwarp.training.twincat import export_twincat

        return export_twincat(policy_path, out, opset=opset, check=check, atol=atol, trusted=trusted, target=target)

    policy = load_policy(policy_path, "cpu", trusted=trusted)  # a pickled module needs trusted (magwarp._io)
    flat, dim = _flat_module(policy, obs_dim)
    example = torch.zeros(2, dim)
    with torch.no_grad():
        action_dim = int(flat(example).shape[-1])
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(flat, (example,), out, dynamo=False, opset_version=int(opset), input_names=["obs"],
                          output_names=["action"], dynamic_axes={"obs": {0: "batch"}, "action": {0: "batch"}})
    model = onnx.load(out)
    meta = {"obs_dim": dim, "action_dim": action_dim, "obs_layout": "achieved_goal, desired_goal, observation",
            "env_id": getattr(policy, "env_id", "")}
    for k, v in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = f"magwarp.{k}", json.dumps(v) if not isinstance(v, str) else v
    onnx.checker.check_model(model)
    onnx.save(model, out)
    diff = check_onnx(out, flat, dim, atol=atol) if check else None
    return {"obs_dim": dim, "action_dim": action_dim, "max_diff": None if diff is None else diff[0],
            "max_abs_diff": None if diff is None else diff[1]}


def check_onnx(path: str, flat: torch.nn.Module, obs_dim: int, *, atol: float = 1e-5, batch: int = 64,
               seed: int = 0, pre=None, post=None) -> tuple[float, float] | None:
    """Largest ``|onnxruntime - torch|`` over random observations, as a fraction of the action range (``flat``'s
    ``action_scale``, 1 where it has none) and in the env's units; None when onnxruntime is missing. Raises if the
    first exceeds ``atol``. ``pre``/``post``: numpy functions applied to the observations before onnxruntime and to
    its output (what a runtime does around a graph that leaves steps to it); a graph with a fixed batch of 1 is run
    one observation at a time."""
    try:
        import onnxruntime as ort
    except ImportError:
        return None
    gen = torch.Generator().manual_seed(seed)
    obs = torch.randn(batch, obs_dim, generator=gen) * 2.0
    with torch.no_grad():
        ref = flat(obs).numpy()
    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    rows = obs.numpy().astype(np.float32)
    rows = rows if pre is None else pre(rows)
    if sess.get_inputs()[0].shape[0] == 1:  # a fixed batch of 1 (the twincat targets): one row per run
        got = np.concatenate([sess.run(["action"], {"obs": rows[i:i + 1]})[0] for i in range(batch)])
    else:
        got = sess.run(["action"], {"obs": rows})[0]
    got = got if post is None else post(got)
    scale = getattr(flat, "action_scale", None)
    scale = np.ones(ref.shape[-1], np.float32) if scale is None else scale.detach().cpu().numpy()
    abs_diff = np.abs(got - ref)
    diff, diff_units = float((abs_diff / scale).max()), float(abs_diff.max())
    if not diff <= atol:
        raise RuntimeError(f"onnxruntime output differs from torch by {diff:.3g} of the action range (> {atol:g}; "
                           f"{diff_units:.3g} in the env's units)")
    return diff, diff_units
