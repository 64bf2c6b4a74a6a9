"""3D viewer streaming through Newton: the null viewer, and a USD file written for real and read back."""

from __future__ import annotations

import numpy as np
import pytest

newton = pytest.importorskip("newton")

from magwarp.layout import benchmark_layout  # noqa: E402
from magwarp.render import SyntheticScene  # noqa: E402
from magwarp.viewer import SceneViewer, make_viewer  # noqa: E402


def _log_all(sv, scene):
    a = scene.arrays()
    sv.log(a["pos"], a["quat"], flags=a["collision"], goals=a["goals"], object_poses=a.get("object_poses"),
           object_goals=a.get("object_goals"), obstacles=a.get("obstacles"))


def test_null_viewer_runs_every_layer():
    layout, m = benchmark_layout("B1")
    scene = SyntheticScene(layout, num_worlds=3, num_movers=m, objects=True)
    sv = SceneViewer(make_viewer("null", num_frames=5), layout, worlds=[2, 0], object_shapes=[scene.object_shape])
    for _ in range(3):
        scene.step()
        _log_all(sv, scene)
    assert sv.frame == 3
    with pytest.raises(ValueError, match="only 1 world"):
        sv.log(np.zeros((1, m, 3), np.float32))
    sv.close()


def test_usd_export_written_and_read_back(tmp_path):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom

    layout, m = benchmark_layout("B0")
    scene = SyntheticScene(layout, num_worlds=4, num_movers=m, objects=True, seed=2)
    path = str(tmp_path / "run.usda")
    sv = SceneViewer(make_viewer("usd", path=path, fps=25, num_frames=10), layout, worlds=4,
                     object_shapes=[scene.object_shape], fps=25)
    history = []
    for _ in range(4):
        scene.step()
        history.append(scene.arrays()["pos"].numpy().copy())
        _log_all(sv, scene)
    sv.close()

    stage = Usd.Stage.Open(path)
    names = {p.GetPath().pathString for p in stage.Traverse()}
    assert "/root/magwarp/tiles/instance_0" in names
    assert len([n for n in names if n.startswith("/root/magwarp/tiles/instance_") and n.count("/") == 4]) == 4 * 12
    for group in ("movers", "safety_zones", "goals", "objects/boxes", "object_goals/boxes", "obstacles"):
        assert f"/root/magwarp/{group}/instance_0" in names, group
    # Mover k of cell c is instance c * M + k; its translation over time follows the scene (plus the cell offset).
    for cell, k in ((0, 0), (3, m - 1)):
        prim = stage.GetPrimAtPath(f"/root/magwarp/movers/instance_{cell * m + k}")
        xf = UsdGeom.Xformable(prim)
        for frame, pos in enumerate(history):
            t = xf.ComputeLocalToWorldTransform(Usd.TimeCode(frame)).ExtractTranslation()
            expected = pos[cell, k] + sv.offsets_np[cell]
            assert np.allclose([t[0], t[1], t[2]], expected, atol=1e-5), (cell, k, frame)


def test_make_viewer_errors(tmp_path):
    with pytest.raises(ValueError, match="unknown viewer 'vr'"):
        make_viewer("vr")
    with pytest.raises(ValueError, match="needs an output path"):
        make_viewer("usd")


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_viser_page_shows_the_movers_in_headless_chromium(tmp_path):
    """The browser viewer binds to 127.0.0.1 and serves a page that draws the scene (screenshot via Chromium)."""
    pytest.importorskip("viser")
    import shutil
    import subprocess

    import imageio.v3 as iio

    from magwarp.render import colors

    port = _free_port()
    layout, m = benchmark_layout("B0")
    scene = SyntheticScene(layout, num_worlds=1, num_movers=m, seed=0)
    viewer = make_viewer("viser", port=port)
    try:
        assert viewer._server.get_host() == "127.0.0.1"
        sv = SceneViewer(viewer, layout)
        for _ in range(3):
            scene.step()
            _log_all(sv, scene)
        chromium = shutil.which("chromium") or shutil.which("chromium-browser")
        if chromium is None:
            pytest.skip("chromium not installed: page not checked")
        shot = tmp_path / "viser.png"

        def missing(budget_ms: int) -> list:
            """The movers whose colour is not on a screenshot taken after ``budget_ms`` of the page's virtual time
            (some pixels close to each mover's colour: lit, so shading is allowed)."""
            subprocess.run([chromium, "--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                            "--enable-unsafe-swiftshader", "--use-angle=swiftshader", "--window-size=960,600",
                            f"--virtual-time-budget={budget_ms}", f"--screenshot={shot}", f"http://127.0.0.1:{port}/"],
                           capture_output=True, timeout=180)
            image = iio.imread(shot)[..., :3].astype(int)
            return [tuple(c) for c in (np.array(colors.mover_color(k)) for k in range(m))
                    if (np.abs(image - c).sum(axis=-1) < 90).sum() <= 30]

        # On a busy machine the scene can reach the page after the first screenshot (the server's threads share the
        # CPU with the software renderer): a longer wait is tried before the check fails.
        for budget in (15000, 45000):
            lost = missing(budget)
            if not lost:
                break
        assert not lost, f"movers' colours {lost} not on the page screenshot"
    finally:
        viewer.close()
