"""``trase-bench view``: a web viewer of a scene folder, rendered on the server (viser).

The browser shows what the project's rasterizer draws at the browser's camera (the numba
kernels on a CPU; gsplat when the scene is put on a GPU, ``device``), sent as a background image; the scene itself never leaves
the server, so a 2-core machine without a GPU serves it. Controls: orbit/fly with the mouse
(viser's camera), a time slider and play, the render modes of ``trase.visualize``, the render
height, click to add the cluster under the cursor (the method's click rule) or, in the "remove"
mode, to give a negative click (the cluster is removed and kept out: a later click at a pixel
where it blends with another picks the other), the
edits of ``trase.edit`` with undo, and export of the edited scene as an edit folder.

Rendering runs in one thread: camera moves and GUI changes only mark a client stale, and the
loop draws the newest state, so a slow frame never queues a backlog of old ones.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from benchmark.errors import UserError

HEIGHTS = ("120", "240", "480")


def camera_from_view(R_c2w: np.ndarray, position: np.ndarray, fov_y: float, aspect: float, height: int,
                     t: float, near: float | None = None):
    """A trase Camera from a viewer's pose (OpenCV axes: +z forward, -y up), vertical field
    of view (radians), aspect (width / height) and render height; ``near``: the model's near
    plane (None: the cameras' default)."""
    from trase.camera import NEAR_PLANE, Camera, intrinsics

    H = int(height)
    W = max(1, round(H * float(aspect)))
    fy = (H / 2.0) / np.tan(float(fov_y) / 2.0)
    w2c = np.eye(4)
    w2c[:3, :3] = R_c2w.T
    w2c[:3, 3] = -R_c2w.T @ np.asarray(position, np.float64)
    return Camera(intrinsics(fy, fy, W / 2.0, H / 2.0), w2c, W, H, time=float(t), name="viewer",
                  near=NEAR_PLANE if near is None else float(near))


class SceneViewer:
    """The viewer of one scene folder (``benchmark.scene.folders``); ``out`` is where Export
    writes the edited scene."""

    def __init__(self, folder, host: str = "127.0.0.1", port: int = 8080, out: Path | None = None,
                 height: int = 240, device: str = "auto", text=None) -> None:
        import viser

        from trase.visualize import MODES, Painter, look_centre

        self.folder = folder
        # text prompts: a benchmark.protocol.text_request.TextRequest (its models, rule and score),
        # its segmenter loaded on the first phrase
        self.text = text
        self.segmenter = None
        self.out = Path(out) if out else folder.path.parent / f"{folder.path.name}-edited"
        self.history = [folder.model]  # undo stack of EditableModels
        self.actions: list[dict] = []  # what each step of the history did
        self.clusters: set[int] = set()
        self.ruled_out: set[int] = set()  # clusters negative clicks removed: later clicks never pick them
        self.clicks: list[tuple[str, int]] = []  # (mode, cluster or -1) of each click handled
        self.device = device
        self.painter = Painter(folder.model, device=device)
        self._lock = threading.RLock()
        self._stale: set[int] = set()
        self._stop = threading.Event()
        self.last_ms = 0.0
        self.frames_drawn = 0
        self.last_frame: np.ndarray | None = None

        cams = [c for _, c in folder.views]
        self.times = folder.times()
        self.centre = look_centre(cams)
        self.home = cams[len(cams) // 2]
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        gui = self.server.gui
        gui.configure_theme(control_width="large")
        self.gui_time = gui.add_slider("time", 0.0, 1.0, 1.0 / max(len(self.times) - 1, 1), float(self.home.time))
        self.gui_play = gui.add_checkbox("play", False)
        self.gui_mode = gui.add_dropdown("mode", MODES, initial_value="rgb")
        self.gui_height = gui.add_dropdown("render height", HEIGHTS, initial_value=str(height))
        with gui.add_folder("selection"):
            self.gui_click = gui.add_dropdown("click", ("add", "remove", "off"), initial_value="add")
            self.gui_clusters = gui.add_text("clusters", "")
            self.gui_text = gui.add_text("text", "", hint="a phrase, e.g. the cup")
            gui.add_button("select by text").on_click(lambda event: self.select_text(event.client))
            gui.add_button("clear").on_click(lambda _: self.set_clusters(set()))
            if folder.selected:
                gui.add_button("the run's selection").on_click(lambda _: self.set_clusters(set(folder.selected)))
        with gui.add_folder("edit"):
            gui.add_button("remove selection").on_click(lambda _: self.apply("remove"))
            gui.add_button("keep only selection").on_click(lambda _: self.apply("extract"))
            self.gui_colour = gui.add_rgb("colour", (255, 60, 40))
            gui.add_button("recolour selection").on_click(lambda _: self.apply("recolor"))
            gui.add_button("undo").on_click(lambda _: self.undo())
            gui.add_button("export").on_click(lambda _: self.export())
        self.gui_status = gui.add_markdown("")
        for handle in (self.gui_time, self.gui_mode, self.gui_height):
            handle.on_update(lambda _: self.mark_all())
        self.gui_clusters.on_update(lambda _: self._clusters_typed())
        self.server.on_client_connect(self._connect)
        self.server.scene.on_click()(self._clicked)
        self._status()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="viewer-render")
        self._thread.start()

    # -- state --------------------------------------------------------------------------
    @property
    def model(self):
        return self.history[-1]

    def selection(self) -> np.ndarray:
        from trase.edit import by_clusters

        return by_clusters(self.model, sorted(self.clusters))

    def set_clusters(self, clusters: set[int], ruled_out: set[int] | None = None) -> None:
        """Select ``clusters``; ``ruled_out``: the negative clicks' clusters (None: none, as after
        clear, a typed list or the run's selection)."""
        with self._lock:
            self.ruled_out = set(ruled_out or ())
            n = self.model.n_clusters
            self.clusters = {int(k) for k in clusters if 0 <= int(k) < n}
            text = ",".join(map(str, sorted(self.clusters)))
            if self.gui_clusters.value != text:
                self.gui_clusters.value = text
            self.painter.set_selection(self.selection())
        self._status()
        self.mark_all()

    def _clusters_typed(self) -> None:
        from benchmark.scene.folders import parse_clusters

        try:
            ks = set(parse_clusters(self.gui_clusters.value))
        except UserError:
            return
        if ks != self.clusters:
            self.set_clusters(ks)

    def apply(self, operation: str) -> None:
        """remove / extract / recolor the selection (one undoable step)."""
        from trase.edit import extract, recolor, remove

        with self._lock:
            sel = self.selection()
            if not sel.any():
                self._status("select something first")
                return
            if operation == "remove":
                new = remove(self.model, sel)
            elif operation == "extract":
                new = extract(self.model, sel)
            else:
                new = recolor(self.model, sel, rgb=tuple(np.asarray(self.gui_colour.value, float) / 255.0))
            self.history.append(new)
            self.actions.append({"operation": operation, "clusters": sorted(self.clusters)})
            self._reset_painter()
        self.set_clusters(set() if operation == "remove" else self.clusters)

    def undo(self) -> None:
        with self._lock:
            if len(self.history) > 1:
                self.history.pop()
                self.actions.pop()
                self._reset_painter()
        self.set_clusters(self.clusters)

    def export(self) -> Path | None:
        from benchmark.scene.edit import write_edit

        with self._lock:
            if not self.actions:
                self._status("nothing to export: no edits yet")
                return None
            try:
                record = write_edit(self.folder, self.model, self.out, "viewer", {"steps": self.actions})
            except (OSError, ValueError) as exc:  # shown in the page: the viewer keeps running
                self._status(f"export failed: {exc}")
                return None
        self._status(f"exported to {record.parent}")
        return record.parent

    def _reset_painter(self) -> None:
        from trase.visualize import Painter

        self.painter = Painter(self.model, device=self.device)

    # -- drawing ------------------------------------------------------------------------
    def mark_all(self) -> None:
        with self._lock:
            self._stale |= set(self.server.get_clients())

    def camera_of(self, client):
        c = client.camera
        from viser import transforms as vtf

        R = vtf.SO3(np.asarray(c.wxyz)).as_matrix()
        return camera_from_view(R, np.asarray(c.position), c.fov, c.aspect, int(self.gui_height.value),
                                float(self.gui_time.value), self.folder.near)

    def draw(self, client) -> np.ndarray:
        with self._lock:
            cam = self.camera_of(client)
            t0 = time.perf_counter()
            img = self.painter.render(cam, self.gui_mode.value)
            self.last_ms = 1000.0 * (time.perf_counter() - t0)
            self.frames_drawn += 1
            self.last_frame = img
        client.scene.set_background_image(img, format="jpeg", jpeg_quality=90)
        return img

    def _loop(self) -> None:
        last_step = time.perf_counter()
        while not self._stop.is_set():
            if self.gui_play.value and time.perf_counter() - last_step > 0.1:
                last_step = time.perf_counter()
                step = 1.0 / max(len(self.times) - 1, 1)
                self.gui_time.value = float((self.gui_time.value + step) % (1.0 + 1e-9))
                self.mark_all()
            with self._lock:
                stale, self._stale = self._stale, set()
            clients = self.server.get_clients()
            for cid in stale:
                if cid in clients:
                    try:
                        self.draw(clients[cid])
                    except Exception as exc:  # noqa: BLE001 - a failed frame is shown, not fatal
                        self._status(f"render failed: {type(exc).__name__}: {exc}")
            if stale:
                self._status()
            time.sleep(0.005)

    def _connect(self, client) -> None:
        c2w = self.home.c2w
        client.camera.up_direction = -c2w[:3, 1]
        client.camera.position = c2w[:3, 3]
        client.camera.look_at = self.centre
        client.camera.fov = float(2.0 * np.arctan(self.home.height / 2.0 / self.home.fy))
        client.camera.on_update(lambda _: self._mark(client.client_id))
        self._mark(client.client_id)

    def _mark(self, client_id: int) -> None:
        with self._lock:
            self._stale.add(client_id)

    def _clicked(self, event) -> None:
        """Add the cluster under the click (the method's click rule), or remove it and keep it out
        (mode "remove": a negative click)."""
        from trase.edit import by_click
        from trase.prompts import positive_pick

        mode = self.gui_click.value
        if mode == "off":
            return
        t0 = time.perf_counter()
        with self._lock:
            cam = self.camera_of(event.client)
            u, v = event.screen_pos[0] * cam.width, event.screen_pos[1] * cam.height
            # a negative click removes a selected cluster where one is under it (as
            # trase.prompts.clicks_to_clusters); a positive one never picks a ruled-out cluster
            def pick(exclude) -> int:
                return by_click(self.model, cam, u, v, rule=self.folder.click_rule, exclude=exclude)[0]

            if mode == "add":  # on a selected cluster: trase.prompts.ON_SELECTED
                k = positive_pick(pick, self.ruled_out, self.clusters, self.folder.on_selected)
            else:
                k = pick(set(range(self.model.n_clusters)) - self.clusters) if self.clusters else -1
                k = k if k >= 0 else pick(self.ruled_out)  # none selected there: the rule's choice among the rest
        self.clicks.append((mode, k))
        if k < 0:
            self._status("the click hit no surface" + (" outside the clusters ruled out" if self.ruled_out else ""))
            return
        if mode == "add":
            self.set_clusters(self.clusters | {k}, self.ruled_out)
        else:  # a negative click
            self.set_clusters(self.clusters - {k}, self.ruled_out | {k})
        done = "added" if mode == "add" else "removed and kept out"
        self._status(f"cluster {k} {done} in {1000 * (time.perf_counter() - t0):.0f} ms")

    def select_text(self, client=None) -> None:
        """Add the clusters the text field's phrase selects in the client's current view (the
        paper's text prompt: detector box -> mask -> lifted to clusters)."""
        from benchmark.protocol.text_choice import text_choice
        from benchmark.protocol.text_request import TextRequest
        from masks.maskset import MaskError

        phrase = self.gui_text.value.strip()
        if not phrase:
            self._status("type a phrase in the text field first")
            return
        request = self.text or TextRequest()
        t0 = time.perf_counter()
        try:
            self.segmenter = self.segmenter or request.load_segmenter()
            with self._lock:
                cam = self.camera_of(client) if client is not None else self.home
                choice = text_choice(self.model, [("the current view", cam)], phrase, lambda _: self.segmenter,
                                     rule=request.mask_rule)
        except (UserError, MaskError) as exc:
            self._status(str(exc))
            return
        self.set_clusters(self.clusters | set(choice.clusters), self.ruled_out)
        self._status(f"text {choice.line()} in {time.perf_counter() - t0:.1f} s")

    def _status(self, note: str = "") -> None:
        m = self.model
        sel = ", ".join(map(str, sorted(self.clusters))) or "none"
        self.gui_status.content = (
            f"**{self.folder.kind}** `{self.folder.path.name}` · {m.num_gaussians} gaussians, {m.n_clusters} clusters  \n"
            f"selected: {sel} · edits: {len(self.actions)} · last frame {self.last_ms:.0f} ms"
            + (f"  \n{note}" if note else ""))

    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.server.stop()


__all__ = ["HEIGHTS", "SceneViewer", "camera_from_view"]
