"""``magwarp bench`` on tiny sizes (tables, JSON, PNG plots, one-line errors) and a light ``import magwarp``."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import imageio.v3 as iio
import pytest

from magwarp import cli
from magwarp.registration import env_ids

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run_cli(capsys, *argv):
    rc = cli.main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def _check_png(path):
    img = iio.imread(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100 and img.std() > 5


def test_bench_render_tiny_writes_json_and_plot(capsys, tmp_path):
    rc, out, err = run_cli(capsys, "bench", "render", "--device", "cpu", "--steps", "2", "--json", str(tmp_path),
                           "--plot", str(tmp_path / "fps.png"), "--", "--worlds", "1", "4", "--px-per-tile", "8",
                           "--repeats", "1")
    assert rc == 0, err
    assert "frames/s" in out and "== wrote" in out
    rows = json.loads((tmp_path / "bench_render.json").read_text())
    assert [r["worlds"] for r in rows] == [1, 4]
    assert all(r["frames_per_s"] > 0 and r["px_per_tile"] == 8 and r["versions"] and r["date_utc"] for r in rows)
    _check_png(tmp_path / "fps.png")


def test_bench_scaling_tiny(capsys, tmp_path):
    rc, out, err = run_cli(capsys, "bench", "scaling", "--device", "cpu", "--steps", "10", "--json",
                           str(tmp_path / "s.json"), "--plot", str(tmp_path), "--", "--max-movers", "50")
    assert rc == 0, err
    assert "ms/step" in out
    rows = json.loads((tmp_path / "s.json").read_text())
    assert {(r["shape"], r["movers"]) for r in rows} == {("circle", 50), ("box", 50)}
    assert all(r["engine"] == "magwarp" and r["ms_per_step"] > 0 for r in rows)
    _check_png(tmp_path / "bench_scaling.png")


def test_bench_env_tiny(capsys, tmp_path):
    rc, out, err = run_cli(capsys, "bench", "env", "--device", "cpu", "--steps", "2", "--json", str(tmp_path),
                           "--", "--envs", "magwarp/TrajectoryPlanningB0-v0", "--num-envs", "1,4", "--adapters-at", "4")
    assert rc == 0, err
    assert "env-steps/s" in out
    rows = json.loads((tmp_path / "bench_env.json").read_text())
    raw = [r for r in rows if r.get("adapter") == "raw" and not r.get("check_inputs")]
    assert sorted(r["num_envs"] for r in raw) == [1, 4] and all(r["env_steps_per_s"] > 0 for r in raw)
    assert not any(r["engine"] == "magbotsim" for r in rows)  # MagBotSim only with --magbotsim


@pytest.mark.parametrize("argv, message", [
    (["bench", "render", "--steps", "0"], "--steps must be >= 1"),
    (["bench", "warp-drive"], "invalid choice"),
    (["bench", "--json", "out.json"], "names one file, but several benchmarks run"),
    (["bench", "render", "--", "--bogus"], "benchmarks/render_fps.py: unrecognized arguments: --bogus"),
    (["bench", "scaling", "--plot", "/no/such/folder/x.png"], "does not exist"),
    (["bench", "--", "--steps", "3"], "options after -- go to one script"),
])
def test_bench_user_mistakes_are_one_line(capsys, argv, message):
    rc, _, err = run_cli(capsys, *argv)
    assert rc == 2, err
    assert err.count("\n") == 1 and message in err and "Traceback" not in err, err


def test_bench_without_the_scripts_says_so(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("MAGWARP_BENCHMARKS", str(tmp_path))
    rc, _, err = run_cli(capsys, "bench", "render")
    assert rc == 1 and err.count("\n") == 1 and "benchmark scripts not found" in err, err


def test_bench_help_lists_kinds(capsys):
    rc, out, _ = run_cli(capsys, "bench", "--help")
    assert rc == 0 and all(k in out for k in ("scaling", "env", "render", "--plot", "--json", "--full"))


def test_import_magwarp_is_light_and_registers_every_id():
    """``import magwarp`` (and so ``magwarp --help``) imports neither torch nor warp, yet registers the env ids."""
    code = ("import sys, magwarp, gymnasium as gym\n"
            "ids = [k for k in gym.registry if k.startswith('magwarp/')]\n"
            "heavy = sorted(m for m in ('torch', 'warp', 'mujoco', 'mujoco_warp', 'magwarp.envs')\n"
            "               if m in sys.modules)\n"
            "print(len(ids), heavy, 'magwarp/PushT-v0' in ids, 'magwarp/TrajectoryPlanningB9-v0' in ids)\n"
            "from magwarp import cli\n"
            "try:\n    cli.main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print('after help', sorted(m for m in ('torch', 'warp') if m in sys.modules))\n")
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    n = len(env_ids())  # every id of the registration table is registered
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith((f"{n} ", "after help"))]
    assert lines == [f"{n} [] True True", "after help []"], res.stdout


def test_lazy_exports_still_work():
    import magwarp

    assert magwarp.Layout.__name__ == "Layout" and callable(magwarp.benchmark_layout)
    assert "Simulator" in dir(magwarp)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        magwarp.nope  # noqa: B018
