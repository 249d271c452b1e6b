"""The web viewer in a real browser: `trase-bench view` serves the tiny run, headless Chromium
(Debian's `chromium`, driven by playwright) shows the scene, and selections made through
viser's API or a click in the page change what is drawn."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import time
import urllib.request

import numpy as np
import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium on this machine (Debian: apt install chromium; "
                                                       ".ci/run installs it)")
WINDOW = {"width": 900, "height": 600}
CANVAS = (slice(40, 560), slice(20, 480))  # rows, cols of the page left of viser's control panel
CLICKABLE_FROM_ROW = 200  # above it, chromium's software-WebGL notice may cover the canvas


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_http(url: str, seconds: float = 60.0) -> None:
    end = time.time() + seconds
    while time.time() < end:
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                if r.status == 200:
                    return
        except OSError:
            time.sleep(0.3)
    raise AssertionError(f"{url} did not answer in {seconds} s")


@pytest.fixture
def browser():
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright (a dev dependency) is not installed")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox", "--use-gl=swiftshader",
                                                              "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"])
        yield b
        b.close()


def _shot(page) -> np.ndarray:
    import cv2

    png = page.screenshot()
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]


def _wait_for(predicate, seconds: float = 30.0) -> None:
    end = time.time() + seconds
    while time.time() < end:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError("timed out")


def test_view_command_draws_the_scene_in_chromium(tiny_run, browser, tmp_path):
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "benchmark.cli", "view", "--run", str(tiny_run), "--port",
                             str(port)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        _wait_http(f"http://127.0.0.1:{port}/")
        page = browser.new_page(viewport=WINDOW)
        page.goto(f"http://127.0.0.1:{port}/")
        page.get_by_text("gaussians").wait_for(timeout=30000)  # our status line: the GUI arrived
        blank = None
        for _ in range(100):  # until the server's first frame is shown
            img = _shot(page)[CANVAS]
            if img.std() > 10 and len(np.unique(img.reshape(-1, 3) // 16, axis=0)) > 20:
                blank = False
                break
            time.sleep(0.2)
        import cv2

        cv2.imwrite(str(tmp_path / "viewer.png"), _shot(page)[..., ::-1])
        assert blank is False, f"the canvas stayed blank (screenshot: {tmp_path / 'viewer.png'})"
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def test_selection_through_the_api_and_a_click_change_the_render(tiny_run, browser, tmp_path):
    from benchmark.scene.folders import open_scene_folder
    from benchmark.scene.viewer import SceneViewer

    folder = open_scene_folder(tiny_run)
    viewer = SceneViewer(folder, port=_free_port(), out=tmp_path / "edited")
    try:
        page = browser.new_page(viewport=WINDOW)
        page.goto(viewer.url())
        _wait_for(lambda: viewer.frames_drawn > 0)
        time.sleep(0.5)
        before_frame, before = viewer.last_frame.copy(), _shot(page)[CANVAS]
        viewer.gui_mode.value = "selection"
        everything = set(range(folder.model.n_clusters))  # the run's own may lie under the panel
        viewer.set_clusters(everything)
        n = viewer.frames_drawn
        _wait_for(lambda: viewer.frames_drawn > n)
        time.sleep(0.5)
        after = _shot(page)[CANVAS]
        assert not np.array_equal(viewer.last_frame, before_frame)
        assert np.abs(after.astype(int) - before.astype(int)).max() > 60  # tinted in the page too

        # a click in the page on a selected object's pixel removes its cluster
        viewer.gui_click.value = "remove"
        sel = viewer.last_frame.astype(int)
        h, w = viewer.last_frame.shape[:2]
        box = page.locator("canvas").first.bounding_box()
        tinted = np.argwhere(np.abs(sel - before_frame.astype(int)).sum(-1) > 60)
        x, y = (tinted[:, 1] + 0.5) * box["width"] / w, (tinted[:, 0] + 0.5) * box["height"] / h
        tinted = tinted[(x < CANVAS[1].stop) & (y > CLICKABLE_FROM_ROW)]  # not under the panel or a notice
        assert len(tinted), "no selected object in the clickable part of the page"
        r, c = tinted[len(tinted) // 2]
        chosen = set(viewer.clusters)
        page.mouse.click(box["x"] + (c + 0.5) * box["width"] / w, box["y"] + (r + 0.5) * box["height"] / h)
        _wait_for(lambda: viewer.clusters != chosen)
        assert viewer.clusters < chosen
        (out,) = chosen - viewer.clusters
        assert viewer.ruled_out == {out}  # a negative click keeps its cluster out
        # an add click at the same pixel picks another cluster (or none), never the ruled-out one
        viewer.gui_click.value = "add"
        time.sleep(0.6)  # not a double click
        page.mouse.move(box["x"] + 2, box["y"] + 2)
        page.mouse.click(box["x"] + (c + 0.5) * box["width"] / w, box["y"] + (r + 0.5) * box["height"] / h)
        _wait_for(lambda: len(viewer.clicks) == 2)
        assert viewer.clicks[1][1] != out and out not in viewer.clusters and viewer.ruled_out == {out}
        # the edits, export and undo
        assert viewer.export() is None  # nothing to export yet
        viewer.apply("remove")
        assert viewer.model.num_gaussians < folder.model.num_gaussians
        exported = viewer.export()
        again = open_scene_folder(exported)
        assert again.kind == "edit" and again.model.num_gaussians == viewer.model.num_gaussians
        viewer.undo()
        assert viewer.model is folder.model
    finally:
        viewer.close()
