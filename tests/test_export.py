"""ONNX export: onnxruntime gives the torch policy's actions within 1e-5 of the action range (skipped without
onnx/onnxruntime)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp.training import RunningMeanStd, mlp, save_policy

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")


def _policy_file(tmp_path, squash: str, rng) -> str:
    torch.manual_seed(int(rng.integers(2**31)))
    n_obs, n_act = 18, 6  # B0 trajectory planning: 3 movers
    rms = RunningMeanStd(n_obs, "cpu", clip=5.0)
    rms.update(torch.randn(256, n_obs) * 3 + 1)
    net = mlp(n_obs, [64, 64], n_act)
    path = str(tmp_path / f"policy_{squash}.pt")
    save_policy(path, net, rms, torch.full((n_act,), 10.0), squash=squash, env_id="magwarp/TrajectoryPlanningB0-v0")
    return path


@pytest.mark.parametrize("squash", ["tanh", "clip"])
def test_onnx_matches_torch(tmp_path, squash, rng):
    from magwarp.training.export import export_onnx

    path = _policy_file(tmp_path, squash, rng)
    out = str(tmp_path / "policy.onnx")
    info = export_onnx(path, out)
    assert info["obs_dim"] == 18 and info["action_dim"] == 6 and info["max_diff"] <= 1e-5
    assert info["max_abs_diff"] == pytest.approx(10.0 * info["max_diff"], rel=1e-6)  # every action scale is 10
    assert info["max_abs_diff"] <= 1e-5  # a 64-wide policy also stays within 1e-5 in the env's units

    policy = torch.jit.load(path, map_location="cpu")
    obs = torch.as_tensor(rng.normal(size=(33, 18)) * 4, dtype=torch.float32)  # a batch size other than the export's
    with torch.no_grad():
        ref = policy(obs).numpy()
    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    (inp,), (outp,) = sess.get_inputs(), sess.get_outputs()
    assert inp.name == "obs" and outp.name == "action"
    got = sess.run(["action"], {"obs": obs.numpy()})[0]
    assert got.shape == (33, 6)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-5, err_msg=str(rng))
    meta = {p.key: p.value for p in onnx.load(out).metadata_props}
    assert meta["magwarp.obs_dim"] == "18" and meta["magwarp.env_id"] == "magwarp/TrajectoryPlanningB0-v0"


def test_export_command(tmp_path, rng, capsys):
    from magwarp.cli import main

    path = _policy_file(tmp_path, "tanh", rng)
    out = tmp_path / "b0.onnx"
    assert main(["export", str(tmp_path / "policy_tanh.pt"), "--onnx", str(out)]) == 0
    assert out.is_file() and "onnxruntime matches torch" in capsys.readouterr().out
    assert main(["export", str(tmp_path / "missing.pt"), "--onnx", str(out)]) == 2
    assert "no policy" in capsys.readouterr().err
    del path


@pytest.mark.parametrize("name", ["b0_ppo", "pushbox_sac", "pusht_sac", "obstacles_sac", "swarm_residual_1024_gate_ep"])
def test_shipped_policies_export(tmp_path, name):
    """The shipped policies (magwarp/pretrained/: 256-wide networks, actions up to 10 m/s^2) pass the export's own
    check."""
    from magwarp.training import pretrained_path
    from magwarp.training.export import export_onnx

    path = pretrained_path(name)
    info = export_onnx(str(path), str(tmp_path / f"{name}.onnx"))
    assert info["max_diff"] <= 1e-5 and info["max_abs_diff"] >= info["max_diff"]
