"""The examples run (with small arguments) and print what they promise."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def run_example(name: str, *args: str) -> str:
    env = dict(os.environ)
    env.setdefault("WARP_CACHE_PATH", str(ROOT / ".warp_cache"))
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / name), *args], capture_output=True, text=True,
                          timeout=300, env=env, cwd=ROOT)
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    return proc.stdout


def test_basic_loop_example():
    out = run_example("basic_loop.py", "--steps", "30", "--worlds", "2", "--device", "cpu")
    assert "2 worlds x 3 movers" in out
    done = re.search(r"done: 30 steps, (\d+) targets reached, (\d+) collisions", out)
    assert done, out
    # every reported collision names what hit what
    for line in out.splitlines():
        if "collision in cycle" in line:
            assert re.search(r"mover \d+ (hit mover \d+|left the tiles)", line), line
    assert int(done.group(1)) > 0, "no mover ever reached a target"


def test_custom_force_model_example():
    out = run_example("custom_force_model.py", "--cycles", "300", "--device", "cpu")
    rows = re.findall(r"^\s+(\d\.\d+)\s+(-?\d\.\d+) /\s+(-?\d\.\d+) m/s\s+(-?\d\.\d+) /\s+(-?\d\.\d+) m/s", out, re.M)
    assert len(rows) == 3, out
    for _t, a, b, c, d in rows:  # simulated speed next to the closed form
        assert float(a) == pytest.approx(float(b), rel=5e-3) and float(c) == pytest.approx(float(d), rel=5e-3)
    assert "world 1 (no current) max speed: 0.00e+00" in out


def test_push_randomized_example():
    out = run_example("push_randomized.py", "--num-envs", "16", "--episodes", "1", "--device", "cpu")
    rows = re.findall(r"half width ([\d.]+)-([\d.]+) cm: success\s+([\d.]+)% of (\d+)", out)
    assert len(rows) == 3 and sum(int(r[3]) for r in rows) == 16, out  # every world's box falls in one bucket
    assert re.search(r"PushWithObstacles, random walls: success [\d.]+% overall", out), out
