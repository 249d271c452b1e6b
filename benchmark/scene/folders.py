"""The folders ``render``, ``edit`` and ``view`` open: a benchmark run, a fitted capture, an
edited scene. Each gives one ``SceneFolder``: the model (geometry, deformation, clusters, the
filter's keep mask, learned features) and the named cameras to look through.

* a run (``results.json``): geometry and fit from the run's stage cache (found by walking up
  from the run to a ``.cache`` holding its stage keys, or given), cameras = the test views;
* a fitted capture (``fit.json``, ``trase-bench fit``): its model/ and segmentation/, cameras
  = every view of the capture;
* an edited scene (``edit.json``, ``trase-bench edit``): its model/ and segmentation/, the
  cameras of the folder it was edited from.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from benchmark.errors import UserError
from benchmark.io import read_json
from benchmark.protocol.text_request import TextRequest

EDIT_FILE, VIEWS_FILE = "edit.json", "views.json"


@dataclasses.dataclass
class SceneFolder:
    kind: str  # "run" | "fit" | "edit"
    path: Path
    model: object  # trase.edit.EditableModel, features on its gaussians when learned
    views: list  # [(name, trase.camera.Camera)]
    selected: list[int]  # clusters the run's prompts chose (runs), else []
    dataset: str  # the benchmark's key, or "capture"
    click_rule: str = "depth"  # the method's click rule for this model (trase.prompts)
    on_selected: str = "nothing"  # what a click on a selected cluster adds (trase.prompts.ON_SELECTED)

    def camera(self, name: str):
        names = [n for n, _ in self.views]
        if name not in names:
            raise UserError(f"{self.path}: no view {name!r} (e.g. {', '.join(names[:3])})")
        return self.views[names.index(name)][1]

    def times(self) -> list[float]:
        return sorted({float(c.time) for _, c in self.views})

    @property
    def near(self) -> float:
        """The near plane the model is rendered with (its cameras'; trase.camera.NEAR_PLANE without any)."""
        from trase.camera import NEAR_PLANE

        return float(self.views[0][1].near) if self.views else NEAR_PLANE


def open_scene_folder(path: Path | str, cache: Path | str | None = None) -> SceneFolder:
    """Open a run, fit or edit folder (see the module doc); a clear error for anything else."""
    path = Path(path)
    if not path.is_dir():
        raise UserError(f"{path}: not a folder")
    if (path / "results.json").is_file():
        return _open_run(path, Path(cache) if cache else None)
    if (path / "fit.json").is_file():
        return _open_fit(path)
    if (path / EDIT_FILE).is_file():
        return _open_edit(path)
    raise UserError(f"{path}: not a run (results.json), a fitted capture (fit.json) or an edited scene ({EDIT_FILE})")


def _with_features(gaussians, features: np.ndarray | None):
    from trase.gaussians import GaussianModel

    if features is None or np.asarray(features).shape[0] != gaussians.num_gaussians:
        return gaussians
    g = gaussians
    return GaussianModel(g.means, g.log_scales, g.quats, g.opacity_logits, g.sh,
                         torch.as_tensor(np.asarray(features, np.float32)), g.active_sh_degree)


def _find_stage(run: Path, stage: str, key: str, cache: Path | None) -> Path:
    if cache is not None:
        found = cache / stage / key
        if not found.is_dir():
            raise UserError(f"{found}: the run's {stage} stage is not in the cache given")
        return found
    for parent in run.parents:
        found = parent / ".cache" / stage / key
        if found.is_dir():
            return found
    raise UserError(f"{run}: its {stage} stage ({key}) is in no .cache above it; pass --cache")


def _open_run(run: Path, cache: Path | None) -> SceneFolder:
    from benchmark.datasets import load_scene
    from benchmark.methods import FittedModel
    from benchmark.pipeline.context import load_geometry, recorded_render_near
    from trase.edit import EditableModel

    rec = read_json(run / "results.json", "results.json")
    if (rec.get("run") or {}).get("kind") == "external":
        raise UserError(f"{run / 'results.json'}: external predictions (trase-bench evaluate) come without a "
                        "model: nothing to render, edit or view")
    stages = rec.get("stages", {})
    for need in ("geometry", "fit"):
        if need not in stages:
            raise UserError(f"{run / 'results.json'}: no {need} stage recorded")
    gaussians, deformation = load_geometry(_find_stage(run, "geometry", stages["geometry"]["key"], cache))
    fitted = FittedModel.load(_find_stage(run, "fit", stages["fit"]["key"], cache))
    scene_dir = Path(rec["scene_dir"])
    if not scene_dir.is_dir():
        raise UserError(f"{run / 'results.json'}: its scene {scene_dir} is gone (regenerate or pass the data root)")
    scene = load_scene(rec["dataset"], scene_dir).with_near(recorded_render_near(rec.get("config", {})))
    model = EditableModel(_with_features(gaussians, fitted.features), deformation, fitted.labels, fitted.keep)
    return SceneFolder("run", run, model, [(v.name, v.camera) for v in scene.test],
                       [int(k) for k in rec.get("selected_clusters", [])], rec["dataset"], **_click_settings(rec))


# how a click chooses clusters in the model, with the value a record from before the setting means
CLICK_SETTINGS = {"click_rule": "depth", "on_selected": "nothing"}


def _click_settings(record: dict) -> dict:
    """The method's click settings (CLICK_SETTINGS) as the record states them: an edit's own
    fields, else a run's or fit's config."""
    prompts = record.get("config", {}).get("method", {}).get("prompts", {})
    return {name: str(record.get(name) or prompts.get(name, default)) for name, default in CLICK_SETTINGS.items()}


def _open_fit(path: Path) -> SceneFolder:
    from benchmark.captures.select import fitted_capture
    from trase.edit import EditableModel

    record, _, fitted, scene = fitted_capture(path)
    model = EditableModel(_with_features(fitted.gaussians, fitted.features), fitted.deformation, fitted.labels,
                          fitted.keep)
    return SceneFolder("fit", path, model, [(v.name, v.camera) for v in scene.test], [], "capture",
                       **_click_settings(record))


def _open_edit(path: Path) -> SceneFolder:
    from trase.camera import Camera
    from trase.edit import load_edited

    record = read_json(path / EDIT_FILE, EDIT_FILE)
    model = load_edited(path)  # with the learned features the PLY carries
    doc = read_json(path / VIEWS_FILE, VIEWS_FILE)
    views = [(v["name"], Camera.from_dict(v["camera"])) for split in ("train", "test") for v in doc.get(split, [])]
    if not views:
        raise UserError(f"{path / VIEWS_FILE}: no views")
    return SceneFolder("edit", path, model, views, [], str(record.get("dataset", "capture")),
                       **_click_settings(record))


def parse_clusters(text: str | None) -> list[int]:
    """"3,7" -> [3, 7]; None or "" -> []."""
    if not text:
        return []
    try:
        return sorted({int(x) for x in text.replace(" ", "").split(",") if x})
    except ValueError:
        raise UserError(f"--clusters {text!r}: expected cluster ids separated by commas, e.g. 3,7") from None


def resolve_selection(folder: SceneFolder, clusters: str | None = None, clicks: tuple[str, ...] = (),
                      selected: bool = False, filtered: bool = True,
                      masks: tuple[str, ...] = (), text=None, found: list | None = None
                      ) -> tuple[list[int], np.ndarray | None]:
    """(cluster ids, [N] bool or None when nothing was asked) from ``--clusters``,
    ``--click VIEW:X,Y`` (the method's click rule; pixel centres), ``--mask VIEW:PATH`` (the
    clusters a 2D mask covers, ``trase.prompts.mask_to_clusters``), ``--selected`` (the
    clusters the run's prompts chose) and ``text`` (a benchmark.protocol.text_request.TextRequest;
    its phrases' TextChoice go to ``found`` where given)."""
    from benchmark.captures.select import mask_prompt, parse_click
    from trase.edit import by_click, by_clusters, by_mask
    from trase.prompts import no_cluster_reason, positive_pick

    ks = set(parse_clusters(clusters))
    n = folder.model.n_clusters
    bad = sorted(k for k in ks if k >= n)
    if bad:
        raise UserError(f"--clusters: no cluster {bad[0]} in {folder.path} (it has {n}: 0..{n - 1})")
    if selected:
        if not folder.selected:
            raise UserError(f"--selected: {folder.path} records no selected clusters")
        ks |= set(folder.selected)
    for click_text in clicks:
        view, x, y = parse_click(click_text)
        cam = folder.camera(view)
        if not (0 <= x < cam.width and 0 <= y < cam.height):
            raise UserError(f"--click {click_text!r}: pixel outside the {cam.width}x{cam.height} view")
        def pick(exclude, cam=cam, u=x + 0.5, v=y + 0.5) -> int:
            return by_click(folder.model, cam, u, v, rule=folder.click_rule, exclude=exclude)[0]

        k = positive_pick(pick, set(), ks, folder.on_selected)
        if k < 0:
            raise UserError(f"--click {click_text!r}: the click hits no surface (rendered alpha below 0.5 there)")
        ks.add(k)
    for text_of_mask in masks:
        cam, mask = mask_prompt(text_of_mask, folder.camera)
        rule = (text or TextRequest()).mask_rule
        hit, _ = by_mask(folder.model, cam, mask, rule=rule)
        if not hit:
            raise UserError(f"--mask {text_of_mask!r}: the mask selects no cluster (rule {rule}: "
                            f"{no_cluster_reason(rule)})")
        ks |= set(hit)
    for choice in text.choices(folder.model, folder.views) if text is not None else []:
        if not choice.clusters:
            raise UserError(f"--text {choice.phrase!r}: its mask in view {choice.view} selects no cluster "
                            f"(rule {choice.rule}: {no_cluster_reason(choice.rule)})")
        ks |= set(choice.clusters)
        if found is not None:
            found.append(choice)
    if not ks and not (clusters or clicks or selected or masks or (text is not None and text.phrases)):
        return [], None
    chosen = sorted(ks)
    return chosen, by_clusters(folder.model, chosen, filtered)


def views_doc(views: list) -> dict:
    """The views.json of an edited scene: its cameras, in the fit folder's format."""
    return {"train": [], "test": [{"name": n, "camera": c.to_dict(), "frame": i} for i, (n, c) in enumerate(views)]}


__all__ = ["EDIT_FILE", "VIEWS_FILE", "SceneFolder", "open_scene_folder", "parse_clusters", "resolve_selection",
           "views_doc"]
