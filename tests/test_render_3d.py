"""3D images of push scenes through MuJoCo's offscreen renderer (EGL or OSMesa); skipped where no GL backend loads."""

from __future__ import annotations

import ctypes.util
import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from magwarp.render import mujoco3d

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _require_gl():
    try:
        return mujoco3d.gl_backend()
    except mujoco3d.GLUnavailableError as e:
        pytest.skip(f"no headless OpenGL backend for MuJoCo here: {e}")


@pytest.fixture(scope="module")
def push_t():
    _require_gl()
    from magwarp.envs.push import PushTEnv

    env = PushTEnv(num_envs=2, device="cpu", render_mode="rgb_array_3d", seed=1)
    env.reset(seed=1)
    return env


def _set_object(env, world, x, y, yaw):
    q = env.backend.object_qpos
    q[world, 0, 0], q[world, 0, 1] = x, y
    q[world, 0, 3], q[world, 0, 6] = math.cos(yaw / 2), math.sin(yaw / 2)
    q[world, 0, 4] = q[world, 0, 5] = 0.0


def test_render_world_shape_dtype_and_content(push_t):
    img = mujoco3d.render_world(push_t, 0, width=160, height=120)
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    assert img.std() > 10  # not a blank image
    # the goal ghost is translucent green: some pixels are clearly greener than red and blue
    g = img.astype(int)
    assert np.sum((g[..., 1] - g[..., 0] > 40) & (g[..., 1] - g[..., 2] > 20)) > 5


def test_frames_change_when_the_object_moves(push_t):
    _set_object(push_t, 1, 0.30, 0.36, 0.0)
    a = mujoco3d.render_world(push_t, 1, width=160, height=120)
    _set_object(push_t, 1, 0.60, 0.36, 1.0)
    b = mujoco3d.render_world(push_t, 1, width=160, height=120)
    assert np.any(a != b)
    # world 0 did not change
    c = mujoco3d.render_world(push_t, 0, width=160, height=120)
    d = mujoco3d.render_world(push_t, 0, width=160, height=120)
    assert np.array_equal(c, d)


def test_render_mode_rgb_array_3d_mosaic(push_t):
    push_t.set_render_worlds(2)
    img = push_t.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[1] > img.shape[0]  # two worlds side by side
    with pytest.raises(ValueError, match="world must be in"):
        mujoco3d.render_world(push_t, 5)


def test_unavailable_backend_is_one_clear_line(monkeypatch):
    monkeypatch.setattr(mujoco3d, "_BACKEND", None)
    monkeypatch.setattr(mujoco3d, "_BACKEND_ERROR", None)
    monkeypatch.setenv("MUJOCO_GL", "disable")
    with pytest.raises(mujoco3d.GLUnavailableError) as e:
        mujoco3d.gl_backend()
    msg = str(e.value)
    assert "\n" not in msg and "MUJOCO_GL" in msg and "libosmesa6" in msg


@pytest.mark.parametrize("backend, lib", [("osmesa", "OSMesa"), ("egl", "EGL")])
def test_each_backend_in_a_fresh_process(backend, lib):
    """PyOpenGL binds one platform per process, so each backend is tried in its own interpreter."""
    if ctypes.util.find_library(lib) is None:
        pytest.skip(f"lib{lib} is not installed (Debian: {'libosmesa6' if lib == 'OSMesa' else 'libegl1'})")
    code = textwrap.dedent("""
        import numpy as np
        from magwarp.layout import Layout
        from magwarp.mjcf import ObjectSpec, generate_mjcf
        import mujoco
        from magwarp.render.mujoco3d import MujocoSceneRenderer, gl_backend
        print("backend", gl_backend())
        xml = generate_mjcf(Layout(np.ones((3, 3), int)), 1, objects=[ObjectSpec("t_shape")])
        m = mujoco.MjModel.from_xml_string(xml)
        r = MujocoSceneRenderer(m, 96, 64)
        img = r.draw(m.qpos0)
        assert img.shape == (64, 96, 3) and img.dtype == np.uint8 and img.std() > 5, (img.shape, img.std())
        print("ok")
    """)
    env = {**os.environ, "MUJOCO_GL": backend}
    env.pop("PYOPENGL_PLATFORM", None)
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    if res.returncode != 0 and "GLUnavailableError" in res.stderr:
        pytest.skip(f"{backend} did not load here: {res.stderr.strip().splitlines()[-1]}")
    assert res.returncode == 0, res.stderr[-2000:]
    assert f"backend {backend}" in res.stdout and "ok" in res.stdout
