"""``trase-bench select``: objects of a fitted capture chosen by clicks or 2D masks, as masks of
its views.

A click ``VIEW:X,Y`` names a view of the capture and a pixel (column X, row Y, as an image
viewer shows them); the method's click rule picks the cluster under it (the rules of
``trase.prompts.click_to_cluster``). A mask ``VIEW:PATH`` names a view and an image file of a
2D mask of it (``imagefiles.read_mask``: the alpha of an RGBA cut-out, else non-zero pixels;
scaled to the view when only its size differs), e.g. what Grounded-SAM gives for a text
prompt; the clusters it covers are chosen (``trase.prompts.mask_to_clusters``, rule
``cover``). The chosen clusters are rendered at every view with the method's filter and alpha
threshold. Masks land in ``<out>/<view>.png`` (0 / 255).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from benchmark.errors import UserError
from benchmark.protocol.text_request import TextRequest

CLICK = re.compile(r"(?P<view>.+):(?P<x>-?\d+(\.\d*)?),(?P<y>-?\d+(\.\d*)?)")


def parse_click(text: str) -> tuple[str, float, float]:
    m = CLICK.fullmatch(text.strip())
    if not m:
        raise UserError(f"--click {text!r}: expected VIEW:X,Y (a view name and a pixel's column and row)")
    return m["view"], float(m["x"]), float(m["y"])


def parse_mask(text: str) -> tuple[str, Path]:
    """``VIEW:PATH`` -> (view, path); the view is everything before the last ':' that is
    followed by an existing file, so view names and paths may hold ':' themselves."""
    for i in [k for k, ch in enumerate(text) if ch == ":"][::-1]:
        if Path(text[i + 1:]).is_file():
            return text[:i], Path(text[i + 1:])
    if ":" not in text:
        raise UserError(f"--mask {text!r}: expected VIEW:PATH (a view's name and a mask image)")
    raise UserError(f"--mask {text!r}: mask image {text.rsplit(':', 1)[1]!r} not found")


def mask_for_view(path: Path, width: int, height: int) -> np.ndarray:
    """[height, width] bool mask prompt from an image file; a file of another size with the
    view's aspect ratio is scaled (area filter, then >= 0.5), any other size is an error."""
    import cv2

    from imagefiles import ImageFileError, read_mask

    try:
        m = read_mask(path)
    except ImageFileError as e:
        raise UserError(str(e)) from None
    h, w = m.shape
    if (w, h) != (width, height):
        if abs(w * height - h * width) > max(w, h):  # not the view's aspect ratio (1 px of rounding)
            raise UserError(f"{path}: mask is {w}x{h}, the view is {width}x{height} (another aspect ratio)")
        m = cv2.resize(m.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA) >= 0.5
    if not m.any():
        raise UserError(f"{path}: the mask is empty (no pixel set), it selects nothing")
    return m


def mask_prompt(text: str, camera_of) -> tuple[object, np.ndarray]:
    """``--mask VIEW:PATH`` -> (the view's camera, bool mask [H, W] at the camera's size);
    ``camera_of(view)`` gives the view's camera or raises a UserError naming what exists."""
    view, path = parse_mask(text)
    cam = camera_of(view)
    return cam, mask_for_view(path, cam.width, cam.height)


def fitted_capture(fit_dir: Path | str):
    """(fit record, method, FittedModel with its geometry, Scene whose test views are all the
    capture's views) of a ``trase-bench fit`` folder."""
    from benchmark.captures.fit import FIT_FILE, VIEWS_FILE
    from benchmark.datasets.scene import Scene, View
    from benchmark.io import read_json
    from benchmark.methods import FittedModel, get_method
    from trase.camera import Camera
    from trase.checkpoint import load_model

    fit_dir = Path(fit_dir)
    if not (fit_dir / FIT_FILE).is_file():
        raise UserError(f"{fit_dir}: not a fitted capture (no {FIT_FILE}; run trase-bench fit first)")
    record = read_json(fit_dir / FIT_FILE, FIT_FILE)
    views_doc = read_json(fit_dir / VIEWS_FILE, VIEWS_FILE)
    gaussians, deformation = load_model(fit_dir / "model")
    method = get_method(record["method"])
    fitted = FittedModel.load(fit_dir / "segmentation", gaussians, deformation, method.settings_class())
    views = [View(name=v["name"], camera=Camera.from_dict(v["camera"]), image_path=Path(v["image"]), frame=int(v["frame"]))
             for split in ("train", "test") for v in views_doc[split]]
    scene = Scene(dataset="capture", sequence=fit_dir.name, root=fit_dir, train=views, test=views,
                  points=np.zeros((0, 3)))
    return record, method, fitted, scene


def parsed_clicks(texts: list[str], scene, fit_dir, positive: bool = True) -> list:
    """``VIEW:X,Y`` texts -> trase.prompts.Click at the pixels' centres (``positive`` False: negative
    clicks, given as --unclick)."""
    from trase.prompts import Click

    names = [v.name for v in scene.test]
    option = "--click" if positive else "--unclick"
    out = []
    for text in texts:
        view, x, y = parse_click(text)
        if view not in names:
            raise UserError(f"{option} {text!r}: no view {view!r} in {fit_dir} (e.g. {', '.join(names[:3])})")
        cam = scene.test[names.index(view)].camera
        if not (0 <= x < cam.width and 0 <= y < cam.height):
            raise UserError(f"{option} {text!r}: pixel outside the {cam.width}x{cam.height} view")
        out.append(Click(x + 0.5, y + 0.5, view, cam.time, names.index(view), positive))
    return out


def select_clicks(fit_dir: Path | str, clicks: list[str], out_dir: Path | str | None = None,
                  masks: list[str] = (), unclicks: list[str] = (), text=None) -> dict:
    """Clusters chosen by ``clicks`` (``VIEW:X,Y``) and ``masks`` (``VIEW:PATH``) and their
    masks at every view, written to ``out_dir`` (default ``<fit>/selection``) ->
    {"clusters", "per_click", "per_mask", "masks": {view: bool [H, W]}}. ``unclicks``: negative
    clicks, taken before the clicks: the cluster under each is kept out, so a click where it
    blends with another picks the other (``per_click`` lists them first). ``text``: a
    benchmark.protocol.text_request.TextRequest, each phrase's choice in ``per_text``."""
    from benchmark.io import atomic_directory, atomic_write_bytes
    from benchmark.methods import click_selection
    from benchmark.protocol.prompts import BenchmarkPrompts
    from trase.prompts import mask_to_clusters

    if not clicks and not masks and not (text and text.phrases):
        raise UserError("give at least one --click VIEW:X,Y, --mask VIEW:PATH or --text PHRASE")
    _, method, fitted, scene = fitted_capture(fit_dir)
    names = [v.name for v in scene.test]
    parsed = parsed_clicks(list(unclicks), scene, fit_dir, positive=False) + parsed_clicks(list(clicks), scene, fit_dir)
    per_click, selected_by_clicks = [], []
    if parsed:
        prompts = BenchmarkPrompts(parsed[0].view_index, parsed[0].view, parsed[0].time, parsed, source="command-line")
        selected_by_clicks, per_click = click_selection(method, fitted, scene, prompts)
    def camera_of(view: str):
        if view not in names:
            raise UserError(f"--mask: no view {view!r} in {fit_dir} (e.g. {', '.join(names[:3])})")
        return scene.test[names.index(view)].camera

    rule = (text or TextRequest()).mask_rule
    per_mask = []
    for text_of_mask in masks:
        cam, mask = mask_prompt(text_of_mask, camera_of)
        per_mask.append(mask_to_clusters(fitted.gaussians, fitted.deformation, cam, mask, fitted.labels, rule=rule))
    per_text = text_choices(fitted, scene, text)
    clusters = sorted(set(selected_by_clicks) | {k for ks in per_mask for k in ks}
                      | {k for c in per_text for k in c.clusters})
    rendered = method.render_selection(fitted, scene, clusters)
    out = Path(out_dir) if out_dir else Path(fit_dir) / "selection"
    from imagefiles import png_bytes

    with atomic_directory(out) as d:
        for name, m in zip(names, rendered):
            atomic_write_bytes(d / f"{name.replace('/', '_')}.png", png_bytes(np.asarray(m, np.uint8) * 255))
        atomic_write_bytes(d / "selection.json", json.dumps(
            {"clicks": list(clicks), "per_click": per_click, "masks": list(masks), "per_mask": per_mask,
             "mask_rule": rule, "text": [c.to_dict() for c in per_text], "clusters": clusters}, indent=1).encode())
    return {"clusters": clusters, "per_click": per_click, "per_mask": per_mask, "per_text": per_text,
            "masks": dict(zip(names, rendered)), "dir": out}


def text_choices(fitted, scene, text) -> list:
    """Each phrase's benchmark.protocol.text_choice.TextChoice on the fitted capture (none without
    ``text``); a phrase whose mask selects nothing is a one-line error."""
    if text is None or not text.phrases:
        return []
    from trase.edit import EditableModel
    from trase.prompts import no_cluster_reason

    model = EditableModel(fitted.gaussians, fitted.deformation, fitted.labels, fitted.keep)
    choices = text.choices(model, [(v.name, v.camera) for v in scene.test])
    for c in choices:
        if not c.clusters:
            raise UserError(f"--text {c.phrase!r}: its mask in view {c.view} selects no cluster "
                            f"(rule {c.rule}: {no_cluster_reason(c.rule)})")
    return choices


__all__ = ["fitted_capture", "mask_for_view", "mask_prompt", "parse_click", "parse_mask", "select_clicks", "text_choices"]
