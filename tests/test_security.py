"""No code runs from a policy or checkpoint file by default: a ``.pt`` with a pickled ``__reduce__`` payload is
refused by ``magwarp eval``, ``magwarp export``, ``magwarp train --resume`` and every Python loader, and its payload
(creating a marker file) never runs. ``--trust`` / ``trusted=True`` opens the old path with a warning; the shipped
policies load without it."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import pytest
import torch

from magwarp import cli
from magwarp.training.pretrained import pretrained_names, pretrained_path



class _Payload:
    """Unpickling this object runs ``open(marker, "w")``: the marker's existence proves that code ran."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.fixture
def evil(tmp_path):
    marker = tmp_path / "PAYLOAD_RAN"
    path = tmp_path / "evil.pt"
    torch.save({"algo": "ppo", "args": {"env_id": "magwarp/PushBox-v0"}, "agent": {}, "x": _Payload(str(marker))},
               path)
    assert not marker.exists()
    return path, marker


def _run(capsys, *argv):
    rc = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.parametrize("argv", [
    ("eval", "TrajectoryPlanningB0", "--policy", "{path}", "--episodes", "1", "--repeats", "1", "--steps", "1",
     "--device", "cpu"),
    ("export", "{path}", "--onnx", "{tmp}/out.onnx"),
    ("train", "--resume", "{path}", "--minutes", "0.01"),
    ("train", "--resume", "{dir}", "--minutes", "0.01"),  # a run folder means its checkpoint.pt
])
def test_cli_refuses_a_malicious_file(capsys, evil, argv, tmp_path):
    path, marker = evil
    if "{dir}" in argv:
        run_dir = tmp_path / "run"
        run_dir.mkdir()
        os.replace(path, run_dir / "checkpoint.pt")
        path = run_dir / "checkpoint.pt"
    argv = [a.format(path=path, tmp=tmp_path, dir=path.parent) for a in argv]
    rc, out, err = _run(capsys, *argv)
    assert rc == 2, err
    assert "refusing to load" in err and "--trust" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    assert not marker.exists()
    assert not (tmp_path / "out.onnx").exists()


def test_python_loaders_refuse_a_malicious_file(evil):
    from magwarp._io import UnsafeFileError, load_checkpoint_file, load_module
    from magwarp.evaluate import EvalError
    from magwarp.evaluate import load_policy as eval_load_policy
    from magwarp.training.common import load_checkpoint
    from magwarp.training.export import export_onnx
    from magwarp.training.policy import load_policy

    path, marker = evil
    for load in (lambda: load_policy(str(path)), lambda: load_checkpoint(str(path), "cpu"),
                 lambda: load_module(str(path)), lambda: load_checkpoint_file(str(path)),
                 lambda: export_onnx(str(path), str(path.parent / "x.onnx"))):
        with pytest.raises(UnsafeFileError, match=r"refusing to load .* pickled Python objects \(e\.g\. [\w.]*open\)"):
            load()
    env = type("E", (), {"device": torch.device("cpu"), "num_envs": 1})()
    with pytest.raises(EvalError, match="refusing to load"):
        eval_load_policy(str(path), env)
    assert not marker.exists()


def test_trusted_loading_warns_and_runs_the_old_path(evil, tmp_path):
    from magwarp.training.common import load_checkpoint
    from magwarp.training.policy import load_policy

    path, marker = evil
    with pytest.warns(UserWarning, match="full unpickler .* runs any code pickled in the file"):
        state = load_checkpoint(str(path), "cpu", trusted=True)
    assert marker.exists() and state["algo"] == "ppo"  # trusted: the file's code did run, as the warning said
    module = torch.nn.Linear(3, 2)
    torch.save(module, tmp_path / "module.pt")
    with pytest.raises(ValueError, match="refusing to load"):
        load_policy(str(tmp_path / "module.pt"))
    with pytest.warns(UserWarning, match="trusted"):
        loaded = load_policy(str(tmp_path / "module.pt"), trusted=True)
    x = torch.randn(4, 3)
    assert torch.equal(loaded(x), module(x))


def test_state_dicts_and_checkpoints_load_without_trust(tmp_path):
    from magwarp.training.common import load_checkpoint, save_checkpoint

    state = {"algo": "sac-her", "args": {"env_id": "magwarp/PushBox-v0", "seed": 1, "lr": 3e-4, "env_kwargs": None},
             "agent": torch.nn.Linear(3, 2).state_dict(), "global_step": 7}
    save_checkpoint(str(tmp_path / "checkpoint.pt"), state)
    loaded = load_checkpoint(str(tmp_path), "cpu")
    assert loaded["args"] == state["args"] and torch.equal(loaded["agent"]["weight"], state["agent"]["weight"])


@pytest.mark.parametrize("path", [pretrained_path(name) for name in pretrained_names()])
def test_shipped_policies_load_without_trust(path):
    import warnings

    from magwarp.training.policy import load_policy, policy_metadata

    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # no 'trusted' warning (torch's own deprecations aside)
        policy = load_policy(path)
    assert policy_metadata(path).get("format") == "magwarp-policy-v1"
    out = policy(torch.zeros(2, policy.obs_dim))
    assert out.shape == (2, policy.action_dim) and torch.isfinite(out).all()


def test_the_payload_really_runs_when_unpickled(evil):
    """The fixture is a real attack: plain pickle loading creates the marker (so the tests above can fail)."""
    path, marker = evil
    torch.load(path, weights_only=False)
    assert marker.exists()
    marker.unlink()
    pickle.loads(pickle.dumps(_Payload(str(marker))))
    assert marker.exists()


@pytest.mark.parametrize("trusted", [False, True])
def test_random_bytes_are_unreadable_files_whatever_they_hold(tmp_path, rng, trusted):
    """Random bytes (bare, behind a pickle header or a zip header) reach the unpickler's internals (an empty stack, a
    short struct, a length beyond memory): every one must be an UnreadableFileError, never a raw IndexError."""
    from magwarp._io import UnreadableFileError, safe_torch_load

    path = tmp_path / "random.pt"
    for i in range(300):
        head = (b"", b"\x80\x02", b"PK\x03\x04")[i % 3]
        path.write_bytes(head + rng.bytes(int(rng.integers(1, 2048))))
        with pytest.raises(UnreadableFileError, match="random.pt"):
            safe_torch_load(str(path), trusted=trusted)
