"""TwinCAT-ready ONNX export (``magwarp export POLICY --onnx OUT --target twincat``) and its metadata.

The graph is the policy's deterministic action and nothing else, for an embedded runtime that runs one prediction per
action period (e.g. Beckhoff TwinCAT's ML runtime, ``FB_MllPrediction``, on a 1 ms PLC task; ``docs/twincat.md``):

* input ``obs`` ``float32 [1, obs_dim]``: the goal-dict observation flattened in
  :data:`magwarp.training.common.OBS_KEYS` order (``achieved_goal, desired_goal, observation``), in the env's units;
* output ``action`` ``float32 [1, action_dim]`` in the env's units (m/s^2 and rad/s^2, or m/s^3 and rad/s^3 for a
  jerk policy): ``scale * squash(net(clip((obs - mean) / std, -c, c)))``, the same arithmetic as the policy file's
  :class:`~magwarp.training.policy.FlatPolicy` (so onnxruntime matches torch to float32 rounding); the observation
  normalisation is inside the graph, ``squash`` is ``tanh`` or a clip to [-1, 1] as the policy was trained;
* a fixed batch of 1 and static shapes everywhere (no dynamic axis, no shape computed at run time).

Operator allow-list (:data:`ALLOWED_OPS`, default ONNX domain only; every node of the written graph is checked and a
graph with any other operator is refused, naming it):

* ``Gemm``, ``MatMul``, ``Add``: the linear layers (weights as initializers);
* ``Sub``, ``Div``: the observation mean and standard deviation;
* ``Clip``, ``Constant``: the normalised-observation clip and the clip squashing (scalar constant bounds);
* ``Relu``, ``Elu``, ``Tanh``: hidden activations (the shipped SAC nets use Relu, the PPO net Elu), tanh squashing;
* ``Mul``: the action scale;
* ``Identity``, ``Flatten``, ``Reshape``: pass-through, with static shapes (a Reshape's shape must be a constant).

No ``Slice``/``Gather``/``Shape``/``Cast``, no control flow (``If``/``Loop``/``Scan``), no other domain.

``--target twincat-mlp`` (:data:`MLP_OPS`) keeps to the operators Beckhoff documents for its real-time runtime's
multi-layer perceptrons (``Gemm``, ``MatMul`` + ``Add``, and the activations ``Tanh``, ``Sigmoid``, ``Softmax``,
``Sin``, ``Cos``, ``Relu``, ``Abs``, ``Identity``, ``Exp``, ``LogSoftmax``, ``Sign``, ``Softplus``, ``Softsign``): the
normalisation is folded into the first layer's weights (``W / std``, ``b - W mean / std``); the graph ends at the
squashing (tanh) or, for a clip-squashed policy, at the last layer; the PLC clips the raw observation to
``mean +- clip * std`` before the call and, after it, clips a clip-squashed output to [-1, 1] and multiplies by the
action scale (all in the metadata). A policy with another activation (the PPO nets' Elu) is refused.

Whether a given TwinCAT product accepts a file is not checked here (``docs/twincat.md`` says what Beckhoff documents).

Metadata (:func:`deployment_metadata`): observation layout (each key's slice of ``obs`` and its bounds), action
components, scale, limits and units, control cycles per action and cycle time, env id and env options (the policy
file's ``eval_env_kwargs`` and training ``env_kwargs``), normaliser (and which parts the PLC must do), ONNX interface
and magwarp version. It is written twice: in the ONNX ``metadata_props`` (one entry ``magwarp.<key>`` per top-level
key, its value JSON) and as a JSON sidecar ``OUT.json``; :func:`read_onnx_metadata` and :func:`read_sidecar` read them
back.
"""

from __future__ import annotations

import copy
import json
import os
import warnings
from typing import Any

import numpy as np
import torch

__all__ = ["ALLOWED_OPS", "MLP_OPS", "PROFILES", "FORMAT", "TwinCatPolicy", "TwinCatMlp", "check_operators",
           "check_static_shapes", "deployment_metadata", "export_twincat", "read_onnx_metadata", "read_sidecar",
           "sidecar_path"]

#: the operators a TwinCAT-target graph may contain (default ONNX domain), see the module docstring
ALLOWED_OPS = frozenset({"Gemm", "MatMul", "Add", "Sub", "Mul", "Div", "Relu", "Elu", "Tanh", "Clip", "Constant",
                         "Identity", "Flatten", "Reshape"})
#: the operators of ``--target twincat-mlp``: those Beckhoff's real-time ML runtime documents for MLPs
MLP_OPS = frozenset({"Gemm", "MatMul", "Add", "Tanh", "Sigmoid", "Softmax", "Sin", "Cos", "Relu", "Abs", "Identity",
                     "Exp", "LogSoftmax", "Sign", "Softplus", "Softsign"})
#: export target -> its operator allow-list
PROFILES = {"twincat": ALLOWED_OPS, "twincat-mlp": MLP_OPS}
FORMAT = "magwarp-twincat-v1"
_PREFIX = "magwarp."
_LIMIT_UNITS = {"v_max": "m/s", "a_max": "m/s^2", "j_max": "m/s^3", "v_max_c": "rad/s", "a_max_c": "rad/s^2",
                "j_max_c": "rad/s^3", "p_max_c": "rad"}
_FLAT_ATTRS = ("net", "obs_mean", "obs_std", "clip", "action_scale", "use_tanh")


class TwinCatPolicy(torch.nn.Module):
    """A :class:`~magwarp.training.policy.FlatPolicy`'s deterministic path as plain operators (no dtype cast)."""

    def __init__(self, flat: torch.nn.Module):
        super().__init__()
        missing = [a for a in _FLAT_ATTRS if not hasattr(flat, a)]
        if missing:
            raise ValueError(f"the twincat target needs a magwarp policy (FlatPolicy: normaliser, net, action scale); "
                             f"this module has no {', '.join(missing)}")
        self.net = flat.net
        self.register_buffer("obs_mean", flat.obs_mean.detach().to(torch.float32).clone())
        self.register_buffer("obs_std", flat.obs_std.detach().to(torch.float32).clone())
        self.register_buffer("action_scale", flat.action_scale.detach().to(torch.float32).clone())
        self.clip = float(flat.clip)
        self.use_tanh = bool(flat.use_tanh)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        x = ((obs - self.obs_mean) / self.obs_std).clamp(-self.clip, self.clip)
        y = self.net(x)
        y = torch.tanh(y) if self.use_tanh else y.clamp(-1.0, 1.0)
        return y * self.action_scale


class TwinCatMlp(torch.nn.Module):
    """The policy's network with the observation normalisation folded into its first layer, squashed by tanh (or, for
    a clip-squashed policy, not squashed) and unscaled: the PLC clips the raw observation to ``mean +- clip * std``
    before, and clips (clip squashing) and scales after (see the module docstring)."""

    def __init__(self, flat: torch.nn.Module):
        super().__init__()
        plain = TwinCatPolicy(flat)  # checks the attributes, float32 copies
        self.net = copy.deepcopy(flat.net)
        first = next(iter(self.net.children()), None)
        w, b = getattr(first, "weight", None), getattr(first, "bias", None)
        obs_dim = plain.obs_mean.numel()
        if w is None or b is None or w.dim() != 2 or w.shape[1] != obs_dim:
            raise ValueError(f"the twincat-mlp target folds the normaliser into the first layer, but the network does "
                             f"not start with a linear layer of {obs_dim} inputs")
        mean, std = plain.obs_mean.double(), plain.obs_std.double()
        with torch.no_grad():  # W (x - m) / s + b = (W / s) x + (b - W m / s), computed in float64
            b.copy_((b.double() - w.double() @ (mean / std)).float())
            w.copy_((w.double() / std).float())
        self.use_tanh = plain.use_tanh

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        y = self.net(obs)
        return torch.tanh(y) if self.use_tanh else y


def check_operators(model, allowed=ALLOWED_OPS, target: str = "twincat") -> list[str]:
    """The sorted operator types of ``model`` (an ``onnx.ModelProto``); raises ValueError naming every node outside
    ``allowed`` (the allow-list of ``target``, or outside the default ONNX domain), and every node with a subgraph."""
    from onnx import AttributeProto

    subgraphs = (AttributeProto.GRAPH, AttributeProto.GRAPHS)  # If/Loop/Scan bodies, or any op that carries one
    bad: dict[str, list[str]] = {}
    for node in model.graph.node:
        op = node.op_type if node.domain in ("", "ai.onnx") else f"{node.domain}.{node.op_type}"
        if op not in allowed or any(a.type in subgraphs for a in node.attribute):
            bad.setdefault(op, []).append(node.name or "?")
    if bad:
        listed = "; ".join(f"{op} ({len(names)} node{'s' * (len(names) > 1)}: {', '.join(names[:3])})"
                           for op, names in sorted(bad.items()))
        raise ValueError(f"the graph uses operators outside the {target} allow-list: {listed}; allowed: "
                         f"{', '.join(sorted(allowed))}")
    return sorted({n.op_type for n in model.graph.node})


def check_static_shapes(model) -> None:
    """Raise ValueError unless every input, output and inferred intermediate tensor has a fixed shape, and every
    Reshape takes its shape from a constant."""
    import onnx

    inferred = onnx.shape_inference.infer_shapes(model, strict_mode=True)
    g = inferred.graph
    for info in [*g.input, *g.output, *g.value_info]:
        dims = info.type.tensor_type.shape.dim
        if not info.type.tensor_type.HasField("shape") or any(not d.HasField("dim_value") for d in dims):
            shown = [d.dim_value if d.HasField("dim_value") else (d.dim_param or "?") for d in dims]
            raise ValueError(f"tensor {info.name!r} has a dynamic shape {shown}; the twincat target needs static "
                             f"shapes")
    constants = {i.name for i in g.initializer} | {o for n in g.node if n.op_type == "Constant" for o in n.output}
    for node in g.node:
        if node.op_type == "Reshape" and node.input[1] not in constants:
            raise ValueError(f"Reshape node {node.name!r} takes its shape from {node.input[1]!r}, not a constant")


def _json_kwargs(text) -> dict[str, Any] | None:
    if text is None or text == "":
        return None
    return json.loads(text) if isinstance(text, str) else dict(text)


def _bounds(values: np.ndarray) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in np.asarray(values, np.float64).reshape(-1)]


def _control(base, rotation: bool) -> tuple[float, dict[str, float | None]]:
    """The env's control cycle time (s) and the motion limits it applies (those of its simulator)."""
    backend = getattr(base, "backend", None)
    if backend is not None and hasattr(backend, "control"):  # mujoco-warp envs (pushing)
        keys = ("v_max", "a_max", "j_max") + (("v_max_c", "a_max_c", "j_max_c", "p_max_c") if rotation else ())
        # the env step over its control cycles: 1 ms whatever the simulation's physics_dt (the PLC's cycle)
        cycle = backend.control.num_cycles * float(backend.dt) / int(base.num_cycles)
        return cycle, {k: getattr(backend.control, k) for k in keys}
    lim = base.sim.model.limits  # the planar simulator (trajectory planning)
    return float(lim.dt64), {"v_max": float(lim.v_max64), "a_max": float(lim.a_max64), "j_max": float(lim.j_max64)}


def deployment_metadata(policy_path: str, module: TwinCatPolicy, env_id: str, stored: dict[str, Any],
                        target: str = "twincat") -> dict:
    """What a PLC program needs besides the graph (see the module docstring), for ``target`` ``twincat`` or
    ``twincat-mlp`` (which leaves the observation clip, the clip squashing and the scale to the PLC). Builds the env
    (one world, CPU) with the policy's evaluation options to read its spaces; raises ValueError if they disagree with
    the policy."""
    if target not in PROFILES:
        raise ValueError(f"unknown twincat target {target!r}; choose one of {', '.join(PROFILES)}")
    import magwarp
    from magwarp.training.common import OBS_KEYS, make_env, parse_env_kwargs

    eval_kwargs = _json_kwargs(stored.get("eval_env_kwargs"))
    train_kwargs = _json_kwargs(stored.get("env_kwargs"))
    kwargs = eval_kwargs if eval_kwargs is not None else (train_kwargs or {})
    env, base = make_env(env_id, 1, "cpu", 0, parse_env_kwargs(json.dumps(kwargs)))
    try:
        obs_space, act_space = base.single_observation_space, base.single_action_space
        num_movers = int(base.num_movers)
        jerk = bool(getattr(base, "learn_jerk", False))
        axes = ["x", "y"] + (["c"] if getattr(base, "learn_mover_c_rotation", False) else [])
        num_cycles = int(base.num_cycles)
        dt, limits = _control(base, "c" in axes)
    finally:
        env.close()
    layout, start = [], 0
    for key in OBS_KEYS:
        box = obs_space[key]
        size = int(np.prod(box.shape))
        layout.append({"key": key, "start": start, "stop": start + size, "low": _bounds(box.low),
                       "high": _bounds(box.high)})
        start += size
    obs_dim, action_dim = int(module.obs_mean.numel()), int(module.action_scale.numel())
    if start != obs_dim or int(np.prod(act_space.shape)) != action_dim:
        raise ValueError(f"{env_id} with {kwargs} has observation size {start} and action size "
                         f"{int(np.prod(act_space.shape))}; the policy {policy_path!r} takes {obs_dim} and gives "
                         f"{action_dim}")
    if action_dim != num_movers * len(axes):
        raise ValueError(f"{env_id}: {action_dim} actions for {num_movers} movers with axes {axes}: the twincat "
                         f"target describes per-mover x/y(/c) actions only")
    lin, rot = ("m/s^3", "rad/s^3") if jerk else ("m/s^2", "rad/s^2")
    full = target == "twincat"
    return {
        "format": FORMAT,
        "target": target,
        "magwarp_version": magwarp.__version__,
        "source": os.path.basename(policy_path),
        "algo": stored.get("algo", ""),
        "env_id": env_id,
        "env_kwargs": kwargs,
        "train_env_kwargs": train_kwargs,
        "onnx": {"input": "obs", "input_shape": [1, obs_dim], "output": "action", "output_shape": [1, action_dim],
                 "dtype": "float32"},
        "obs_layout": layout,
        "obs_normalization": {
            "in_graph": "nodes" if full else "folded into the first layer",
            "plc_clips_obs": not full,  # to [raw_low, raw_high] before the call (twincat-mlp)
            "mean": module.obs_mean.tolist(), "std": module.obs_std.tolist(), "clip": module.clip,
            "raw_low": (module.obs_mean - module.clip * module.obs_std).tolist(),
            "raw_high": (module.obs_mean + module.clip * module.obs_std).tolist(),
        },
        "action": {
            "quantity": "jerk" if jerk else "acceleration",
            "components": [{"mover": i, "axis": a, "unit": rot if a == "c" else lin}
                           for i in range(num_movers) for a in axes],
            "squash": "tanh" if module.use_tanh else "clip",
            "squash_in_graph": full or module.use_tanh,
            "scale_in_graph": full,
            "scale": module.action_scale.tolist(),
            "low": _bounds(act_space.low),
            "high": _bounds(act_space.high),
        },
        "control": {"num_cycles": num_cycles, "cycle_time_s": dt, "action_period_s": num_cycles * dt,
                    "num_movers": num_movers, "limits": limits,
                    "limit_units": {k: _LIMIT_UNITS[k] for k in limits}},
    }


def _plc_steps(meta: dict[str, Any]):
    """What the PLC does around the graph, as the metadata says: (observation -> graph input, graph output -> action)
    on float32 arrays; None where it does nothing."""
    norm, action = meta["obs_normalization"], meta["action"]
    pre = post = None
    if norm["plc_clips_obs"]:
        low, high = np.float32(norm["raw_low"]), np.float32(norm["raw_high"])

        def pre(obs):
            return np.clip(obs, low, high)
    if not (action["squash_in_graph"] and action["scale_in_graph"]):
        squash, scale = not action["squash_in_graph"], np.float32(action["scale"])

        def post(y):
            return (np.clip(y, -1.0, 1.0) if squash else y) * scale
    return pre, post


def sidecar_path(out: str) -> str:
    """The JSON sidecar written next to ``out`` (``OUT.json``)."""
    return f"{out}.json"


def read_onnx_metadata(path: str) -> dict[str, Any]:
    """The ``magwarp.*`` metadata of an exported ONNX file, decoded (keys without the prefix)."""
    import onnx

    model = onnx.load(path, load_external_data=False)
    return {p.key[len(_PREFIX):]: json.loads(p.value) for p in model.metadata_props if p.key.startswith(_PREFIX)}


def read_sidecar(out: str) -> dict[str, Any]:
    """The JSON sidecar of the exported file ``out``."""
    with open(sidecar_path(out), encoding="utf-8") as f:
        return json.load(f)


def export_twincat(policy_path: str, out: str, *, opset: int = 17, check: bool = True, atol: float = 1e-5,
                   trusted: bool = False, target: str = "twincat") -> dict:
    """Write the ``target`` (``twincat`` or ``twincat-mlp``) graph of ``policy_path`` to ``out`` and its metadata
    sidecar to ``OUT.json``.

    Returns ``{"obs_dim", "action_dim", "max_diff", "max_abs_diff", "operators", "sidecar", "metadata"}``
    (``max_diff``: :func:`magwarp.training.export.check_onnx`'s, None without onnxruntime or ``check``; for
    ``twincat-mlp`` the check runs the PLC's part too: observation clip before, squash clip and scale after)."""
    import onnx

    from magwarp.training.export import check_onnx
    from magwarp.training.policy import load_policy, policy_metadata

    policy = load_policy(policy_path, "cpu", trusted=trusted)
    file = os.path.join(policy_path, "policy.pt") if os.path.isdir(policy_path) else policy_path
    try:
        stored = policy_metadata(file)
    except Exception:  # noqa: BLE001 - not a TorchScript file: it carries no metadata
        stored = {}
    env_id = stored.get("env_id") or str(getattr(policy, "env_id", "") or "")
    if not env_id:
        raise ValueError(f"{policy_path!r} records no env id: the twincat target describes the env the policy was "
                         f"trained for (a policy.pt written by magwarp train records it)")
    if target not in PROFILES:
        raise ValueError(f"unknown twincat target {target!r}; choose one of {', '.join(PROFILES)}")
    flat = getattr(policy, "flat", policy)
    plain = TwinCatPolicy(flat).eval()
    module = plain if target == "twincat" else TwinCatMlp(flat).eval()
    meta = deployment_metadata(policy_path, plain, env_id, stored, target)  # before writing: a mismatch leaves no file
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    example = torch.zeros(1, meta["onnx"]["input_shape"][1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scripted = torch.jit.script(module)  # the policy file's net is TorchScript: a trace cannot enter it
        torch.onnx.export(scripted, (example,), out, dynamo=False, opset_version=int(opset), input_names=["obs"],
                          output_names=["action"])
    model = onnx.load(out)
    try:
        meta["onnx"]["opset"] = int(opset)
        meta["onnx"]["operators"] = check_operators(model, PROFILES[target], target)
        check_static_shapes(model)
    except ValueError:
        os.remove(out)
        raise
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = _PREFIX + key, json.dumps(value)
    onnx.checker.check_model(model)
    onnx.save(model, out)
    with open(sidecar_path(out), "w", encoding="utf-8") as f:
        json.dump(meta, f, indent=1)
        f.write("\n")
    diff = None
    if check:  # against the policy file's own path, not the rewrite that was exported
        pre, post = _plc_steps(meta)
        try:
            diff = check_onnx(out, flat, meta["onnx"]["input_shape"][1], atol=atol, pre=pre, post=post)
        except RuntimeError as e:
            os.remove(out)
            os.remove(sidecar_path(out))
            if target == "twincat":
                raise
            std = plain.obs_std
            smallest = f"smallest: {float(std.min()):.2g}, obs[{int(std.argmin())}]"
            raise RuntimeError(f"{e}: folding the normaliser into the first layer costs float32 precision where an "
                               f"observation's std is tiny ({smallest}); --target twincat keeps it as separate nodes"
                               ) from None
    return {"obs_dim": meta["onnx"]["input_shape"][1], "action_dim": meta["onnx"]["output_shape"][1],
            "max_diff": None if diff is None else diff[0], "max_abs_diff": None if diff is None else diff[1],
            "operators": meta["onnx"]["operators"], "sidecar": sidecar_path(out), "metadata": meta}
