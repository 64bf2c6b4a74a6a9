"""``magwarp export --target twincat``: every shipped policy exports with a fixed batch of 1 and only allowed operators,
onnxruntime equals torch, the metadata round-trips (ONNX metadata_props == JSON sidecar), and graphs or policies
outside the contract are refused with a message that names the problem (skipped without onnx/onnxruntime)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from magwarp.training import RunningMeanStd, mlp, pretrained_path, save_policy
from magwarp.training.common import OBS_KEYS
from magwarp.training.policy import load_policy, policy_metadata

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

from onnx import TensorProto, helper  # noqa: E402

from magwarp.training.export import export_onnx  # noqa: E402
from magwarp.training.twincat import (ALLOWED_OPS, FORMAT, MLP_OPS, check_operators,  # noqa: E402
                                      check_static_shapes, read_onnx_metadata, read_sidecar)

SHIPPED = ["b0_ppo", "pushbox_sac", "pusht_sac", "obstacles_sac"]
# |onnxruntime - torch| as a fraction of the action range on fresh random observations: the export's own check (64
# observations, seed 0) holds 1e-5, but over 5000 observations float32 summation order reaches 1.3e-5 (both targets)
ATOL = 3e-5


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_policy_twincat(tmp_path, name, rng):
    path = pretrained_path(name)
    out = str(tmp_path / f"{name}.onnx")
    info = export_onnx(path, out, target="twincat")
    policy, stored = load_policy(path), policy_metadata(path)
    n_obs, n_act = policy.obs_dim, policy.action_dim
    assert (info["obs_dim"], info["action_dim"]) == (n_obs, n_act) and info["max_diff"] <= 1e-5

    model = onnx.load(out)
    shapes = [[d.dim_value if d.HasField("dim_value") else d.dim_param for d in v.type.tensor_type.shape.dim]
              for v in (*model.graph.input, *model.graph.output)]
    assert shapes == [[1, n_obs], [1, n_act]]  # a fixed batch of 1, no dynamic axis
    ops = {n.op_type for n in model.graph.node}
    assert ops <= ALLOWED_OPS and sorted(ops) == info["operators"]
    assert {"Gemm", "Sub", "Div", "Clip", "Mul"} <= ops  # layers, the normaliser and the scale are in the graph
    assert ("Tanh" in ops) == bool(policy.flat.use_tanh)

    # Metadata: ONNX metadata_props and the sidecar say the same, and describe this policy and its env.
    meta = read_onnx_metadata(out)
    assert meta == read_sidecar(out) == info["metadata"]
    assert meta["format"] == FORMAT and meta["target"] == "twincat" and meta["env_id"] == stored["env_id"]
    assert meta["env_kwargs"] == json.loads(stored["eval_env_kwargs"])
    assert meta["train_env_kwargs"] == json.loads(stored["env_kwargs"])
    assert [e["key"] for e in meta["obs_layout"]] == list(OBS_KEYS)
    bounds = [(e["start"], e["stop"]) for e in meta["obs_layout"]]
    assert bounds[0][0] == 0 and bounds[-1][1] == n_obs and all(a[1] == b[0] for a, b in zip(bounds, bounds[1:]))
    control, action = meta["control"], meta["action"]
    assert control["num_cycles"] == meta["env_kwargs"]["num_cycles"] and control["cycle_time_s"] == 0.001
    assert control["limits"]["a_max"] == 10.0 and control["limit_units"]["a_max"] == "m/s^2"
    assert len(action["components"]) == n_act == control["num_movers"] * 2
    assert {c["unit"] for c in action["components"]} == {"m/s^2"} and action["quantity"] == "acceleration"
    np.testing.assert_array_equal(action["scale"], policy.flat.action_scale.numpy())
    assert action["high"] == [10.0] * n_act and action["squash"] == ("tanh" if policy.flat.use_tanh else "clip")
    assert action["squash_in_graph"] and action["scale_in_graph"] and not meta["obs_normalization"]["plc_clips_obs"]
    np.testing.assert_array_equal(meta["obs_normalization"]["mean"], policy.flat.obs_mean.numpy())

    # onnxruntime, one observation per run as a PLC calls it, equals the torch policy on random observations.
    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    obs = (rng.normal(size=(16, n_obs)) * 2).astype(np.float32)
    got = np.concatenate([sess.run(["action"], {"obs": obs[i:i + 1]})[0] for i in range(len(obs))])
    with torch.no_grad():
        ref = policy(torch.as_tensor(obs)).numpy()
    np.testing.assert_allclose(got / action["scale"], ref / action["scale"], rtol=0, atol=ATOL, err_msg=str(rng))
    with pytest.raises(Exception, match="(?i)dimension|shape"):
        sess.run(["action"], {"obs": obs[:2]})  # the batch really is fixed


def _plc_run(out: str, obs: np.ndarray) -> np.ndarray:
    """A twincat-mlp file run as docs/twincat.md tells a PLC to: clip the raw observation, one prediction per
    observation, clip a clip-squashed output, scale."""
    meta = read_sidecar(out)
    norm, action = meta["obs_normalization"], meta["action"]
    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    rows = np.clip(obs, np.float32(norm["raw_low"]), np.float32(norm["raw_high"]))
    y = np.concatenate([sess.run(["action"], {"obs": rows[i:i + 1]})[0] for i in range(len(rows))])
    return (y if action["squash_in_graph"] else np.clip(y, -1.0, 1.0)) * np.float32(action["scale"])


@pytest.mark.parametrize("name", ["pushbox_sac", "pusht_sac"])
def test_shipped_policy_twincat_mlp(tmp_path, name, rng):
    """Gemm, Relu and Tanh only (what Beckhoff documents for its real-time MLPs); with the PLC's part, it is the
    policy."""
    path = pretrained_path(name)
    out = str(tmp_path / f"{name}.onnx")
    info = export_onnx(path, out, target="twincat-mlp")
    assert info["operators"] == ["Gemm", "Relu", "Tanh"] and set(info["operators"]) <= MLP_OPS
    meta = read_onnx_metadata(out)
    assert meta == read_sidecar(out) and meta["target"] == "twincat-mlp"
    assert meta["obs_normalization"]["plc_clips_obs"] and not meta["action"]["scale_in_graph"]
    policy = load_policy(path)
    obs = (rng.normal(size=(16, policy.obs_dim)) * 2).astype(np.float32)  # many beyond the clip: the PLC clips them
    with torch.no_grad():
        ref = policy(torch.as_tensor(obs)).numpy()
    np.testing.assert_allclose(_plc_run(out, obs) / 10.0, ref / 10.0, rtol=0, atol=ATOL, err_msg=str(rng))


def test_twincat_mlp_refusals_and_clip_squash(tmp_path, rng):
    out = tmp_path / "m.onnx"
    with pytest.raises(ValueError, match=r"outside the twincat-mlp allow-list: Elu \(3 nodes"):
        export_onnx(pretrained_path("b0_ppo"), str(out), target="twincat-mlp")
    # The obstacle corners never varied in training (std 1e-4): W / std in float32 is too coarse; the check says so.
    with pytest.raises(RuntimeError, match=r"float32 precision.*smallest: 0.0001.*--target twincat"):
        export_onnx(pretrained_path("obstacles_sac"), str(out), target="twincat-mlp")
    assert not out.exists() and not (tmp_path / "m.onnx.json").exists()
    # A clip-squashed ReLU policy: the graph ends at the last layer, the PLC clips and scales.
    torch.manual_seed(1)
    rms = RunningMeanStd(18, "cpu", clip=5.0)
    rms.update(torch.randn(64, 18) * 0.3 + 0.4)
    path = str(tmp_path / "policy.pt")
    net = mlp(18, [32, 32], 6, act=torch.nn.ReLU)
    with torch.no_grad():
        net[-1].weight.mul_(30.0)  # pre-squash outputs well beyond [-1, 1]: many get clipped, some not
    save_policy(path, net, rms, torch.full((6,), 10.0), squash="clip", env_id="magwarp/TrajectoryPlanningB0-v0")
    info = export_onnx(path, str(out), target="twincat-mlp")
    assert info["operators"] == ["Gemm", "Relu"] and not info["metadata"]["action"]["squash_in_graph"]
    obs = (rng.normal(size=(16, 18)) * 3).astype(np.float32)
    with torch.no_grad():
        ref = load_policy(path)(torch.as_tensor(obs)).numpy()
    clipped = np.abs(ref) == 10.0
    assert 0 < clipped.sum() < clipped.size, str(rng)
    np.testing.assert_allclose(_plc_run(str(out), obs) / 10.0, ref / 10.0, rtol=0, atol=ATOL, err_msg=str(rng))


def _graph(nodes, inputs, outputs, initializers=()):
    return helper.make_model(helper.make_graph(nodes, "g", inputs, outputs, list(initializers)),
                             opset_imports=[helper.make_opsetid("", 17)])


def test_forbidden_operators_are_named():
    x = helper.make_tensor_value_info("obs", TensorProto.FLOAT, [1, 4])
    y = helper.make_tensor_value_info("action", TensorProto.FLOAT, [1, 2])
    consts = [helper.make_tensor(n, TensorProto.INT64, [1], [v]) for n, v in
              (("starts", 0), ("ends", 2), ("axes", 1))]
    nodes = [helper.make_node("Tanh", ["obs"], ["t"], name="tanh"),
             helper.make_node("Slice", ["t", "starts", "ends", "axes"], ["action"], name="cut")]
    sliced = _graph(nodes, [x], [y], consts)
    with pytest.raises(ValueError, match=r"Slice \(1 node: cut\)") as err:
        check_operators(sliced)
    assert "Tanh" not in str(err.value).split("allowed:")[0]  # only the offending operator is named
    assert check_operators(sliced, ALLOWED_OPS | {"Slice"}) == ["Slice", "Tanh"]

    custom = _graph([helper.make_node("Relu", ["obs"], ["action"], name="r", domain="com.example")], [x], [x])
    with pytest.raises(ValueError, match=r"com\.example\.Relu"):
        check_operators(custom)
    loop_body = helper.make_graph([], "body", [], [])
    branchy = _graph([helper.make_node("If", ["obs"], ["action"], name="branch", then_branch=loop_body,
                                       else_branch=loop_body)], [x], [y])
    with pytest.raises(ValueError, match=r"If \(1 node: branch\)"):
        check_operators(branchy)


def test_dynamic_shapes_are_refused():
    dyn = helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", 4])
    out = helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 4])
    with pytest.raises(ValueError, match=r"'obs' has a dynamic shape \['batch', 4\]"):
        check_static_shapes(_graph([helper.make_node("Tanh", ["obs"], ["action"])], [dyn], [out]))
    x = helper.make_tensor_value_info("obs", TensorProto.FLOAT, [1, 4])
    flat = helper.make_tensor_value_info("action", TensorProto.FLOAT, [4])
    shape = helper.make_tensor_value_info("shape", TensorProto.INT64, [1])
    with pytest.raises(ValueError, match="Reshape node 'rs' takes its shape from 'shape'"):
        check_static_shapes(_graph([helper.make_node("Reshape", ["obs", "shape"], ["action"], name="rs")],
                                   [x, shape], [flat]))
    static = [helper.make_tensor("s", TensorProto.INT64, [1], [4])]
    check_static_shapes(_graph([helper.make_node("Reshape", ["obs", "s"], ["action"], name="rs")], [x], [flat], static))


def _b0_policy(tmp_path, act=torch.nn.ELU, n_obs=18, env_id="magwarp/TrajectoryPlanningB0-v0") -> str:
    torch.manual_seed(0)
    rms = RunningMeanStd(n_obs, "cpu", clip=5.0)
    rms.update(torch.randn(64, n_obs))
    path = str(tmp_path / "policy.pt")
    save_policy(path, mlp(n_obs, [16], 6, act=act), rms, torch.full((6,), 10.0), squash="tanh", env_id=env_id)
    return path


def test_policy_outside_the_contract_is_refused(tmp_path):
    out = tmp_path / "p.onnx"
    with pytest.raises(ValueError, match=r"Softplus \(1 node"):  # an activation outside the allow-list
        export_onnx(_b0_policy(tmp_path, act=torch.nn.Softplus), str(out), target="twincat")
    assert not out.exists()  # nothing half-written is left
    with pytest.raises(ValueError, match="observation size 18 .* takes 10"):
        export_onnx(_b0_policy(tmp_path, n_obs=10), str(out), target="twincat")
    with pytest.raises(ValueError, match="records no env id"):
        export_onnx(_b0_policy(tmp_path, env_id=""), str(out), target="twincat")
    with pytest.raises(ValueError, match="unknown export target 'plc'"):
        export_onnx(_b0_policy(tmp_path), str(out), target="plc")
    assert not out.exists() and not (tmp_path / "p.onnx.json").exists()
    # Without env options in the file (a bare save_policy), the env's defaults are described: B0, 40 cycles.
    info = export_onnx(_b0_policy(tmp_path), str(out), target="twincat")
    assert info["metadata"]["env_kwargs"] == {} and info["metadata"]["control"]["num_cycles"] == 40


@pytest.mark.parametrize("env_id, options, n_obs, n_act, units, limits", [
    ("magwarp/TrajectoryPlanningB0-v0", {"learn_jerk": True, "num_cycles": 30, "j_max": 50.0}, 24, 6,
     {"m/s^3"}, {"v_max": 2.0, "a_max": 10.0, "j_max": 50.0}),
    ("magwarp/PushBox-v0", {"learn_mover_c_rotation": True, "a_max_c": 20.0}, 11, 3, {"m/s^2", "rad/s^2"},
     {"v_max": 2.0, "a_max": 10.0, "j_max": 100.0, "v_max_c": 122.17305, "a_max_c": 20.0, "j_max_c": 610.86524,
      "p_max_c": None}),
])
def test_metadata_follows_env_options(tmp_path, env_id, options, n_obs, n_act, units, limits):
    """Jerk policies are described in m/s^3 with their env's limits; a yaw ("c") axis per mover in rad."""
    torch.manual_seed(0)
    rms = RunningMeanStd(n_obs, "cpu")
    path = str(tmp_path / "policy.pt")
    save_policy(path, mlp(n_obs, [8], n_act, act=torch.nn.ReLU), rms, torch.full((n_act,), 3.0), squash="tanh",
                env_id=env_id, metadata={"eval_env_kwargs": json.dumps(options)})
    meta = export_onnx(path, str(tmp_path / "p.onnx"), target="twincat")["metadata"]
    assert meta["env_kwargs"] == options and meta["train_env_kwargs"] is None
    assert {c["unit"] for c in meta["action"]["components"]} == units
    assert [c["axis"] for c in meta["action"]["components"]] == (["x", "y"] * 3 if n_act == 6 else ["x", "y", "c"])
    assert meta["action"]["quantity"] == ("jerk" if options.get("learn_jerk") else "acceleration")
    assert meta["control"]["limits"] == limits and meta["control"]["num_cycles"] == options.get("num_cycles", 40)
    assert meta["action"]["scale"] == [3.0] * n_act  # the policy's own scale, whatever the env's bounds


def test_twincat_command(tmp_path, capsys):
    from magwarp.cli import main

    out = tmp_path / "push.onnx"
    assert main(["export", "pretrained:pushbox_sac", "--onnx", str(out), "--target", "twincat"]) == 0
    text = capsys.readouterr().out
    assert "obs [1, 8] -> action [1, 2]" in text and "one action every 160 cycles of 1 ms" in text
    assert read_sidecar(str(out))["env_id"] == "magwarp/PushBox-v0"
    for argv, message in (
        (["--target", "plc"], "invalid choice: 'plc'"),
        (["--target", "twincat", "--obs-dim", "8"], "--obs-dim is not used with --target twincat"),
    ):
        assert main(["export", "pretrained:pushbox_sac", "--onnx", str(out), *argv]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1
    assert main(["export", "pretrained:b0_ppo", "--onnx", str(out), "--target", "twincat-mlp"]) == 2
    err = capsys.readouterr().err  # the policy's mistake: the message alone, exit 2
    assert err.startswith("magwarp export: error: the graph uses operators outside the twincat-mlp allow-list: Elu (3 "
                          "nodes") and len(err.strip().splitlines()) == 1
    assert main(["export", "pretrained:pushbox_sac", "--onnx", str(out), "--target", "twincat-mlp"]) == 0
    assert "the PLC's part: clip obs to obs_normalization.raw_low/raw_high" in capsys.readouterr().out
    bad = _b0_policy(tmp_path, env_id="")
    assert main(["export", bad, "--onnx", str(tmp_path / "b.onnx"), "--target", "twincat"]) == 2
    err = capsys.readouterr().err
    assert "records no env id" in err and len(err.strip().splitlines()) == 1


def test_ppo_relu_policy_fits_twincat_mlp(tmp_path):
    """``--activation relu`` trains a PPO policy that the Gemm-and-activations target accepts (the default Elu is
    refused): a tiny run, exported, its graph within Beckhoff's MLP list."""
    from magwarp.training import ppo

    run = tmp_path / "run"
    kwargs = '{"layout": [[1, 1, 1], [1, 1, 1], [1, 1, 1]], "num_movers": 1}'
    ppo.train(ppo.parse_args(["--env-id", "magwarp/TrajectoryPlanning-v0", "--env-kwargs", kwargs, "--device", "cpu",
                              "--num-envs", "16", "--num-steps", "8", "--hidden", "16,16", "--activation", "relu",
                              "--total-steps", "256", "--no-progress", "--eval-steps", "4", "--out", str(run)]))
    info = export_onnx(str(run / "policy.pt"), str(tmp_path / "p.onnx"), target="twincat-mlp")
    assert "Relu" in info["operators"] and set(info["operators"]) <= MLP_OPS
