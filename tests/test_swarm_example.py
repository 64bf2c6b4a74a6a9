"""The swarm scalability study example runs at small sizes and writes its plot."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_swarm_scaling_example(tmp_path):
    png = tmp_path / "swarm.png"
    env = dict(os.environ)
    env.setdefault("WARP_CACHE_PATH", str(ROOT / ".warp_cache"))
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "swarm_scaling.py"), "--movers", "8", "32",
                           "--seconds", "1.2", "--device", "cpu", "--png", str(png)], capture_output=True, text=True,
                          timeout=300, env=env, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = re.findall(r"^\s*(\d+) movers on (\d+)x\d+ tiles: ([\d.]+) goals/s/mover", proc.stdout, re.M)
    assert [(int(m), int(s)) for m, s, _ in rows] == [(8, 6), (32, 12)], proc.stdout
    assert png.stat().st_size > 1000
