"""magwarp from a wheel (not an editable install, not the source tree): ``magwarp train``, ``eval`` and ``export``
work, and the shipped policies are package data found by name.

A fresh venv gets magwarp itself as a wheel built from this checkout; its dependencies come from the current
environment through a ``.pth`` file (a venv with all of them installed would take minutes). Every command runs from
a temporary folder outside the repository with no PYTHONPATH, so only the installed wheel can be imported.
"""

from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
TINY = '{"layout": [[1, 1, 1], [1, 1, 1], [1, 1, 1]], "num_movers": 1}'
SKIP = shutil.ignore_patterns(".git", ".venv*", "runs", "build", "dist", "*.egg-info", "__pycache__", ".warp_cache",
                              ".pytest_cache", "out", "results", "*.gif")


@pytest.fixture(scope="module")
def venv(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("wheel")
    src = shutil.copytree(REPO, root / "src", ignore=SKIP)  # the build writes build/ and egg-info next to its source
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", str(root / "wheels"),
                    str(src)], check=True, cwd=root)
    wheel = next((root / "wheels").glob("magwarp-*.whl"))
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(root / "venv")], check=True)
    python = root / "venv" / "bin" / "python"
    subprocess.run([*pip, "--python", str(python), "install", "--no-deps", "--no-index", str(wheel)], check=True)
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             check=True, capture_output=True, text=True).stdout.strip()
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"], *site.getsitepackages()}
    Path(purelib, "_magwarp_test_deps.pth").write_text("\n".join(sorted(deps)) + "\n")
    return root


def _run(venv: Path, *cmd: str) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PATH"] = f"{venv / 'venv' / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    cwd = venv / "work"
    cwd.mkdir(exist_ok=True)
    proc = subprocess.run(list(cmd), cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"{cmd} exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


def test_wheel_trains_evaluates_exports_and_ships_the_policies(venv):
    bin_ = venv / "venv" / "bin"
    where = _run(venv, str(bin_ / "python"), "-c", "import magwarp, magwarp.training as t; print(magwarp.__file__); "
                 "p = t.load_pretrained('pushbox_sac'); print(t.pretrained_names(), p.obs_dim, p.action_dim)")
    assert str(venv / "venv") in where.splitlines()[0] and "site-packages" in where, where
    shipped = sorted(f.stem for f in (REPO / "magwarp" / "pretrained").glob("*.pt"))
    assert "pushbox_sac" in shipped and where.splitlines()[1] == f"{shipped} 8 2", where  # every file, in the wheel

    out = _run(venv, str(bin_ / "magwarp"), "train", "magwarp/TrajectoryPlanning-v0", "--algo", "ppo",
               "--device", "cpu", "--num-envs", "32", "--minutes", "0.33", "--out", "runs/tiny", "--env-kwargs", TINY, "--target", "0.3",
               "--args", "--num-steps 8 --hidden 32,32 --eval-steps 20 --eval-every 5 --target-eval-steps 60 "
                         "--no-progress --log-every 5")
    run = venv / "work" / "runs" / "tiny"
    for name in ("policy.pt", "checkpoint.pt", "progress.csv", "curve.png", "run.json"):
        assert (run / name).is_file(), name
    assert "ppo done" in out and "time to target 0.3" in out

    out = _run(venv, str(bin_ / "magwarp"), "eval", "magwarp/TrajectoryPlanning-v0", "--policy", "runs/tiny/policy.pt",
               "--device", "cpu", "--episodes", "4", "--repeats", "2", "--steps", "20", "--env-kwargs", TINY)
    assert "Success" in out or "success" in out
    out = _run(venv, str(bin_ / "magwarp"), "export", "runs/tiny", "--onnx", "tiny.onnx")
    assert "onnxruntime matches torch" in out and (venv / "work" / "tiny.onnx").is_file()
    out = _run(venv, str(bin_ / "magwarp"), "eval", "magwarp/TrajectoryPlanningB0-v0", "--policy", "pretrained:b0_ppo",
               "--device", "cpu", "--episodes", "2", "--repeats", "1", "--steps", "5")
    assert "policy=pretrained:b0_ppo" in out and "env options from" in out
    # the README's main job, from the wheel (small: the test times nothing)
    out = _run(venv, str(bin_ / "magwarp"), "demo", "--device", "cpu", "--num-envs", "16", "--steps", "2",
               "--video-steps", "2", "--worlds-shown", "4", "--out-dir", "demo_out")
    assert "env-steps/s" in out and (venv / "work" / "demo_out" / "demo.gif").is_file()
    assert (venv / "work" / "demo_out" / "demo.png").is_file()
