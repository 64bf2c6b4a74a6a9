"""Every mistake on the command line ends in one line on stderr and a non-zero exit code, never a traceback;
``--debug`` shows the traceback. Covers the cases of issue 25 (corrupt files, impossible paths, full disks, failing
or NaN-returning policies, NaN env options) and the imageio ``__del__`` traceback after an unwritable ``render -o``."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from magwarp import cli
from magwarp.training.pretrained import pretrained_path

REPO = Path(__file__).resolve().parent.parent
POLICY = Path(pretrained_path("b0_ppo"))  # a shipped policy (package data)
EVAL = ("--episodes", "1", "--repeats", "1", "--steps", "2", "--device", "cpu")


def _run(capsys, *argv):
    rc = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def _one_line(rc: int, err: str, *needles: str) -> None:
    assert rc != 0
    lines = [line for line in err.strip().splitlines() if not line.startswith("magwarp: ") or "error" in line]
    assert len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], lines[0]


@pytest.fixture(scope="module")
def policy_module(tmp_path_factory):
    """An importable module of bad policies (raising, NaN, overflowing float64, wrong shape)."""
    folder = tmp_path_factory.mktemp("policies")
    (folder / "bad_policies_i25.py").write_text(textwrap.dedent("""
        import torch

        def raises(obs):
            raise RuntimeError("the policy broke")

        def nan(obs):
            return torch.full((obs["observation"].shape[0], 6), float("nan"))

        def overflow(obs):
            return torch.full((obs["observation"].shape[0], 6), 1e40, dtype=torch.float64)

        def late_nan(obs):
            late_nan.calls = getattr(late_nan, "calls", 0) + 1
            value = float("nan") if late_nan.calls > 2 else 0.0
            return torch.full((obs["observation"].shape[0], 6), value)

        def wrong_shape(obs):
            return torch.zeros(3)
    """))
    sys.path.insert(0, str(folder))
    yield folder
    sys.path.remove(str(folder))


@pytest.fixture
def files(tmp_path):
    text = tmp_path / "notes.txt"
    text.write_text("not a policy\n")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(POLICY.read_bytes()[:2000])  # a truncated zip archive
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(os.urandom(512))
    no_args = tmp_path / "no_args.pt"
    torch.save({"algo": "ppo", "agent": {}}, no_args)
    module = tmp_path / "module.pt"
    torch.save(torch.nn.Linear(3, 6), module)  # pickled module with the wrong input size for B0 (18 inputs)
    scripted = tmp_path / "scripted.pt"
    torch.jit.script(torch.nn.Linear(3, 6)).save(str(scripted))
    return {"text": text, "corrupt": corrupt, "garbage": garbage, "no_args": no_args, "module": module,
            "scripted": scripted, "tmp": tmp_path}


@pytest.mark.parametrize("argv, needles", [
    (("export", "{text}", "--onnx", "{tmp}/a.onnx"), ["not a torch file"]),
    (("export", "{corrupt}", "--onnx", "{tmp}/a.onnx"), ["policy file"]),
    (("export", "{garbage}", "--onnx", "{tmp}/a.onnx"), ["not a torch file"]),
    (("export", str(POLICY), "--onnx", "/etc/hostname/x.onnx"), ["/etc/hostname"]),
    (("export", str(POLICY), "--onnx", "{tmp}/a.onnx", "--obs-dim", "0"), ["--obs-dim", "must be >= 1", "0"]),
    (("export", str(POLICY), "--onnx", "{tmp}/a.onnx", "--obs-dim", "5"), ["--obs-dim", "is 5", "size 18"]),
    (("train", "--resume", "{corrupt}"), ["checkpoint"]),
    (("train", "--resume", "{garbage}"), ["checkpoint"]),
    (("train", "--resume", "{no_args}"), ["not a magwarp training checkpoint", "'args'"]),
    (("eval", "TrajectoryPlanningB0", "--policy", "{text}", *EVAL), ["not a torch file"]),
    (("eval", "TrajectoryPlanningB0", "--policy", "{corrupt}", *EVAL), ["policy file"]),
    (("eval", "TrajectoryPlanningB0", "--policy", "{module}", "--trust", *EVAL), ["raised RuntimeError", "shapes"]),
    (("eval", "TrajectoryPlanningB0", "--policy", "{scripted}", *EVAL), ["raised"]),
    (("eval", "TrajectoryPlanningB0", "--policy", "os:getcwd", *EVAL), ["'os:getcwd' raised TypeError"]),
    (("eval", "TrajectoryPlanningB0", "--policy", "bad_policies_i25:raises", *EVAL), ["the policy broke"]),
    (("eval", "TrajectoryPlanningB0", "--policy", "bad_policies_i25:nan", *EVAL), ["non-finite actions"]),
    (("eval", "TrajectoryPlanningB0", "--policy", "bad_policies_i25:overflow", *EVAL), ["non-finite actions"]),
    (("eval", "TrajectoryPlanningB0", "--policy", "bad_policies_i25:late_nan", *EVAL), ["non-finite actions"]),
    (("eval", "TrajectoryPlanningB0", "--policy", "bad_policies_i25:wrong_shape", *EVAL), ["shape (3,)"]),
    (("eval", "TrajectoryPlanningB0", "--env-kwargs", '{"reward_per_step": NaN}', *EVAL), ["finite", "NaN"]),
    (("eval", "TrajectoryPlanningB0", "--env-kwargs", '{"reward_per_step": 1e400}', *EVAL), ["finite"]),
    (("eval", "TrajectoryPlanningB0", "--env-kwargs", '{"num_cycles": 2.5}', *EVAL), ["num_cycles", "2.5"]),
    (("eval", "TrajectoryPlanningB0", "--json", "/dev/full", *EVAL), ["No space left"]),
    (("eval", "TrajectoryPlanningB0", "--episodes", "1", "--repeats", "1", "--steps", "1", "--device",
      "cuda:7"), ["cuda:7"]),
])
def test_mistakes_are_one_line_with_a_non_zero_exit(capsys, files, policy_module, argv, needles):
    for key, value in files.items():
        argv = [a.replace(f"{{{key}}}", str(value)) for a in argv]
    rc, out, err = _run(capsys, *argv)
    _one_line(rc, err, *needles)
    if "--policy" in argv:
        assert "Success Rate" not in out  # never a table of results from a broken policy


def test_render_onto_a_full_disk_is_one_line(capsys, tmp_path, monkeypatch):
    import magwarp.render.io as rio

    def full(path, data):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(rio, "write_encoded", full)
    for name in ("x.gif", "x.png"):
        rc, out, err = _run(capsys, "render", "--synthetic", "--layout", "B0", "--worlds", "1", "--steps", "2",
                            "--device", "cpu", "-o", tmp_path / name)
        _one_line(rc, err, "No space left on device")
        assert rc == 1


def test_debug_shows_the_traceback(capsys, files):
    with pytest.raises(Exception, match="not a torch file"):
        cli.main(["--debug", "export", str(files["text"]), "--onnx", str(files["tmp"] / "a.onnx")])


def test_unwritable_gif_has_no_traceback_from_imageio():
    """imageio retried the write from its writer's ``__del__`` and printed a second traceback at exit."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    res = subprocess.run([sys.executable, "-m", "magwarp", "render", "--synthetic", "--layout", "B0", "--worlds", "1",
                          "--steps", "2", "--device", "cpu", "-o", "/proc/x.gif"], capture_output=True, text=True,
                         env=env, timeout=300)
    assert res.returncode != 0
    assert "Traceback" not in res.stderr and "Exception ignored" not in res.stderr, res.stderr
    errors = [line for line in res.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "/proc/x.gif" in errors[0], res.stderr


def test_trusted_load_warns_in_one_line(capsys, files):
    with pytest.warns(UserWarning, match="runs any code pickled in the file"):
        rc, out, err = _run(capsys, "export", files["module"], "--onnx", files["tmp"] / "m.onnx", "--obs-dim", "3",
                            "--trust")
    assert rc == 0, err
    line = cli._one_line_warning(UserWarning("loading x\nwith the full unpickler"), UserWarning, "f.py", 3)
    assert line == "magwarp: UserWarning: loading x with the full unpickler\n"
