"""The bare-kernel ceiling of a B0 env step: one fused Warp kernel doing the step's physics and nothing else.

One thread per world holds its movers in registers for the whole step: ``num_cycles`` cycles (40) of 1 ms, each mover
with its x/y acceleration command norm-clipped to ``a_max`` and its speed capped at ``v_max`` (semi-implicit Euler,
float32), the impedance hold of z, roll, pitch and yaw (critically damped springs, small angles), then the wall check
(circle footprint on the full rectangle of tiles) and the mover-mover check (every pair of circles); the world stops at
its first collision. The state is read once from a start state and written once: every step does the same work from
the same poses (as the env's "physics alone" row resets before each step). No observations, rewards, resets or
bookkeeping: what a hand-fused kernel costs for the physics alone, the bound an env step is compared with
(``benchmarks/env_throughput.py`` prints env / ceiling beside it).

    python benchmarks/ceiling.py                                  # cpu (+ cuda:0 when present)
    python benchmarks/ceiling.py --device cuda:0 --num-envs 4096,65536,1048576,2097152 --json out.json
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from common import finish, start_run  # noqa: E402

# B0: 4 x 3 tiles of 0.24 m, 3 movers (MagBotSim's benchmark layout), circle collision radius 0.11 m.
B0_TILES, B0_MOVERS, TILE = (4, 3), 3, 0.24
RADIUS, MASS, HOVER_Z = 0.11, 1.24, 0.0075
K_Z, K_ROT = 100.0, (0.1, 0.1, 1.0)
INERTIA = (2.5e-3, 2.5e-3, 5.0e-3)


@functools.cache
def make_ceiling_kernel(num_movers: int):
    """The fused step kernel for ``num_movers`` movers per world (loops over movers unroll)."""
    M = int(num_movers)
    Rows3 = wp.types.matrix(shape=(M, 3), dtype=wp.float32)
    Rows2 = wp.types.matrix(shape=(M, 2), dtype=wp.float32)

    @wp.kernel(module="unique", enable_backward=False)
    def ceiling_step(
        num_cycles: int,
        # Model:
        dt: float,
        a_max: float,
        v_max: float,
        extent: wp.vec2,
        radius: float,
        k_z: float,
        d_z: float,
        hover_z: float,
        inv_mass: float,
        k_rot: wp.vec3,
        d_rot: wp.vec3,
        inv_inertia: wp.vec3,
        # State in:
        cmd: wp.array2d(dtype=wp.vec2),
        start_pos: wp.array2d(dtype=wp.vec3),
        # State out:
        pos: wp.array2d(dtype=wp.vec3),
        vel: wp.array2d(dtype=wp.vec3),
        rot: wp.array2d(dtype=wp.vec3),
        omega: wp.array2d(dtype=wp.vec3),
        halted: wp.array(dtype=wp.int32),
    ):
        w = wp.tid()
        P = Rows3()
        V = Rows3()
        R = Rows3()
        Om = Rows3()
        C = Rows2()
        for m in range(M):
            P[m] = start_pos[w, m]
            C[m] = cmd[w, m]
        stopped = int(0)
        for c in range(num_cycles):
            if stopped == 1:
                break
            for m in range(M):
                a = C[m]
                n = wp.length(a)
                if n > a_max:
                    a = a * (a_max / n)
                v = wp.vec2(V[m, 0], V[m, 1]) + a * dt
                s = wp.length(v)
                if s > v_max:
                    v = v * (v_max / s)
                vz = V[m, 2] + (k_z * (hover_z - P[m, 2]) - d_z * V[m, 2]) * inv_mass * dt
                V[m] = wp.vec3(v[0], v[1], vz)
                P[m] = P[m] + V[m] * dt
                om = Om[m]
                r = R[m]
                tau = wp.cw_mul(-k_rot, r) - wp.cw_mul(d_rot, om)
                om = om + wp.cw_mul(tau, inv_inertia) * dt
                Om[m] = om
                R[m] = r + om * dt
            hit = int(0)
            for i in range(M):
                if P[i, 0] < radius or P[i, 1] < radius or P[i, 0] > extent[0] - radius or P[i, 1] > extent[1] - radius:
                    hit = 1
                for j in range(M):
                    if j > i:
                        dx = P[i, 0] - P[j, 0]
                        dy = P[i, 1] - P[j, 1]
                        if dx * dx + dy * dy <= 4.0 * radius * radius:
                            hit = 1
            stopped = hit
        for m in range(M):
            pos[w, m] = P[m]
            vel[w, m] = V[m]
            rot[w, m] = R[m]
            omega[w, m] = Om[m]
        halted[w] = stopped

    return ceiling_step


class Ceiling:
    """``num_worlds`` B0 worlds for the ceiling kernel on ``device``; :meth:`step` runs one env step's physics."""

    def __init__(self, num_worlds: int, device: str, num_cycles: int = 40, seed: int = 0):
        self.device = wp.get_device(device)
        self.num_worlds, self.num_cycles = int(num_worlds), int(num_cycles)
        m = B0_MOVERS
        rng = np.random.default_rng(seed)
        cx = (np.arange(B0_TILES[0]) + 0.5) * TILE
        cy = (np.arange(B0_TILES[1]) + 0.5) * TILE
        centres = np.array([(x, y) for x in cx for y in cy])
        start = np.zeros((self.num_worlds, m, 3), np.float32)
        for w in range(min(self.num_worlds, 64)):  # 64 distinct start sets, repeated
            start[w, :, :2] = centres[rng.choice(len(centres), m, replace=False)]
        start[64:] = np.resize(start[:64], start[64:].shape) if self.num_worlds > 64 else start[64:]
        start[..., 2] = HOVER_Z
        cmd = rng.uniform(-10.0, 10.0, (self.num_worlds, m, 2)).astype(np.float32)
        dev = self.device
        self.start = wp.array(start, dtype=wp.vec3, device=dev)
        self.cmd = wp.array(cmd, dtype=wp.vec2, device=dev)
        z3 = functools.partial(wp.zeros, (self.num_worlds, m), dtype=wp.vec3, device=dev)
        self.pos, self.vel, self.rot, self.omega = z3(), z3(), z3(), z3()
        self.halted = wp.zeros(self.num_worlds, dtype=wp.int32, device=dev)
        self.kernel = make_ceiling_kernel(m)
        d_rot = [2.0 * np.sqrt(k * i) for k, i in zip(K_ROT, INERTIA)]
        self.inputs = [self.num_cycles, 1e-3, 10.0, 2.0, wp.vec2(B0_TILES[0] * TILE, B0_TILES[1] * TILE), RADIUS, K_Z,
                       2.0 * np.sqrt(K_Z * MASS), HOVER_Z, 1.0 / MASS, wp.vec3(*K_ROT), wp.vec3(*d_rot),
                       wp.vec3(*(1.0 / np.asarray(INERTIA))), self.cmd, self.start]
        self.outputs = [self.pos, self.vel, self.rot, self.omega, self.halted]
        self.graph = None
        self._launch()  # compile/load
        if self.device.is_cuda:
            with wp.ScopedCapture(device=dev, force_module_load=False) as cap:
                self._launch()
            self.graph = cap.graph

    def _launch(self) -> None:
        wp.launch(self.kernel, dim=self.num_worlds, device=self.device, inputs=self.inputs, outputs=self.outputs)

    def step(self) -> None:
        if self.graph is not None:
            wp.capture_launch(self.graph)
        else:
            self._launch()


def ceiling_ms(num_worlds: int, device: str, steps: int = 50) -> dict:
    """Median ms per step (over 5 chunks of ``steps // 5``) of the ceiling kernel; env-steps/s from it."""
    c = Ceiling(num_worlds, device)
    for _ in range(3):
        c.step()
    wp.synchronize_device(device)
    chunk, samples = max(1, steps // 5), []
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(chunk):
            c.step()
        wp.synchronize_device(device)
        samples.append((time.perf_counter() - t) / chunk)
    ms = float(np.median(samples) * 1e3)
    halted = float(c.halted.numpy().mean())
    return {"ceiling_ms": ms, "ceiling_steps_per_s": num_worlds / (ms / 1e3), "ceiling_halted": halted}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", "--devices", default=None, help="cpu or cuda:N (default: cpu, plus cuda:0 when present)")
    p.add_argument("--num-envs", default=None, help="comma-separated sizes (default: 1..4096 on CPU, 4096..2M on GPU)")
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    info, devices = start_run(args.device)
    rows = []
    for device in devices:
        sizes = ([int(s) for s in args.num_envs.split(",")] if args.num_envs else
                 ([1, 64, 1024, 4096] if device == "cpu" else [4096, 16384, 65536, 262144, 1048576, 2097152]))
        for n in sizes:
            rows.append({"device": device, "num_envs": n, **ceiling_ms(n, device, args.steps)})
    return finish(rows, ["device", "num_envs", ("ceiling_ms", "ms/step"), ("ceiling_steps_per_s", "env-steps/s"),
                         ("ceiling_halted", "halted")], info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
