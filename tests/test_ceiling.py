"""benchmarks/ceiling.py: the bare B0 step kernel against a plain numpy reference (it must do the physics it is
timed for), and its timing helper as a CPU smoke check."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import ceiling  # noqa: E402


def reference_step(start, cmd, cycles: int):
    """The ceiling kernel's step in float64 numpy, world by world."""
    dt, a_max, v_max, r = 1e-3, 10.0, 2.0, ceiling.RADIUS
    ext = np.array(ceiling.B0_TILES) * ceiling.TILE
    d_z = 2 * np.sqrt(ceiling.K_Z * ceiling.MASS)
    k_rot, inertia = np.array(ceiling.K_ROT), np.array(ceiling.INERTIA)
    d_rot = 2 * np.sqrt(k_rot * inertia)
    W, M = cmd.shape[:2]
    pos, vel = start.astype(np.float64).copy(), np.zeros((W, M, 3))
    rot, om = np.zeros((W, M, 3)), np.zeros((W, M, 3))
    halted = np.zeros(W, dtype=np.int32)
    for w in range(W):
        for _ in range(cycles):
            if halted[w]:
                break
            for m in range(M):
                a = cmd[w, m].astype(np.float64)
                n = np.linalg.norm(a)
                a = a * (a_max / n) if n > a_max else a
                v = vel[w, m, :2] + a * dt
                s = np.linalg.norm(v)
                v = v * (v_max / s) if s > v_max else v
                force_z = ceiling.K_Z * (ceiling.HOVER_Z - pos[w, m, 2]) - d_z * vel[w, m, 2]
                vz = vel[w, m, 2] + force_z / ceiling.MASS * dt
                vel[w, m] = (*v, vz)
                pos[w, m] += vel[w, m] * dt
                om[w, m] += (-k_rot * rot[w, m] - d_rot * om[w, m]) / inertia * dt
                rot[w, m] += om[w, m] * dt
            p = pos[w, :, :2]
            hit = ((p < r) | (p > ext - r)).any()
            for i in range(M):
                for j in range(i + 1, M):
                    hit |= np.sum((p[i] - p[j]) ** 2) <= 4 * r * r
            halted[w] = int(hit)
    return pos, vel, rot, om, halted


def test_ceiling_kernel_matches_numpy(rng):
    c = ceiling.Ceiling(70, "cpu", num_cycles=40, seed=int(rng.integers(1 << 30)))
    cmd = rng.uniform(-15, 15, (70, ceiling.B0_MOVERS, 2)).astype(np.float32)
    start = c.start.numpy()
    start[5, 0, 0] = ceiling.RADIUS + 1e-4  # this world drives a mover off the tiles and stops at that cycle
    cmd[5, 0] = (-10.0, 0.0)
    c.start.assign(start)
    c.cmd.assign(cmd)
    c.step()
    pos, vel, rot, om, halted = reference_step(start, cmd, 40)
    assert halted[5] == 1
    np.testing.assert_allclose(c.pos.numpy(), pos, atol=1e-5)
    np.testing.assert_allclose(c.vel.numpy(), vel, atol=1e-4)
    np.testing.assert_allclose(c.omega.numpy(), om, atol=1e-6)
    np.testing.assert_array_equal(c.halted.numpy(), halted)
    assert np.abs(c.pos.numpy() - c.start.numpy()).max() > 1e-3  # the movers did move


def test_ceiling_ms_smoke():
    row = ceiling.ceiling_ms(16, "cpu", steps=5)
    assert row["ceiling_ms"] > 0 and row["ceiling_steps_per_s"] > 0
