"""``gaussian-grouping`` and ``sa4d``: identity classification from tracked masks.

learn: identity encodings (a table per gaussian, or SA4D's field of position and time) and a
linear classifier trained on the frozen geometry against the training views' track ids
(``tracks``). group: each gaussian's class, the argmax of the classifier on its encoding (the
"clusters" of the benchmark's reports and oracle). segment: a click's class is the classifier's
argmax on the identity rendered under it, at the click's view and time; the gaussians of the
chosen classes are those whose class probability exceeds ``selection.prob_threshold``, then
the convex-hull step of the public code; they are rendered at the test views (alpha >= 0.5).
For SA4D the probabilities are those of the field at each test view's time.

Top-level imports stay light: ``trase-bench methods`` imports this module to list it.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from benchmark.methods import FittedModel, Method, MethodError, click_view, combine_clicks
from trase_bench_grouping.settings import CLICK_VOTES, GG_PRESETS, HULLS, SA4D_PRESETS, GroupingSettings

NO_TRACK = 0  # the tracked ids' class of pixels no track holds: a click on it selects nothing


class GaussianGrouping(Method):
    """Gaussian Grouping: per-gaussian identity encodings classified into tracked-mask ids."""

    presets = GG_PRESETS
    FEATURE_FIELDS = ("features",)
    needs_tracks = True  # the masks stage writes tracked ids (masks.tracked) for this method
    temporal = False  # SA4D: the encoding is a field of position and time

    # -- settings ----------------------------------------------------------------------
    def check_settings(self, settings: GroupingSettings) -> None:
        from benchmark.config import ConfigError

        f, s = settings.features, settings.selection
        if f.dim < 1 or f.n_classes < 2:
            raise ConfigError(f"method.features: dim {f.dim} and n_classes {f.n_classes} must be >= 1 and >= 2")
        if s.hull not in HULLS:
            raise ConfigError(f"method.selection.hull={s.hull!r}: choose one of {', '.join(HULLS)}")
        if settings.render_rule not in ("alone", "visible"):
            raise ConfigError(f"method.render_rule={settings.render_rule!r}: choose alone or visible")
        if s.click_votes not in CLICK_VOTES:
            raise ConfigError(f"method.selection.click_votes={s.click_votes!r}: choose one of {', '.join(CLICK_VOTES)}")

    # -- learn -------------------------------------------------------------------------
    def learn(self, scene, gaussians, deformation, masks_dir: Path, config: GroupingSettings, work_dir: Path,
              progress: bool = True) -> tuple[np.ndarray, dict]:
        """Encodings [N, D] float32 (SA4D: the field at t = 0.5) and the trained weights in the info."""
        import torch

        from masks.tracked import INFO_FILE, ids_path, load_ids, load_tracks_info
        from trase_bench_grouping.identity import pack
        from trase_bench_grouping.train import IdentityTrainingError, train_identity

        masks_dir = Path(masks_dir)
        missing = [v.name for v in scene.train if not ids_path(masks_dir, v.name).is_file()]
        if len(missing) == len(scene.train):
            raise MethodError(f"{ids_path(masks_dir, scene.train[0].name)}: no tracked ids for the training views "
                              f"({self.name} needs tracked masks: --set masks.tracking=SOURCE)")

        def load(view):
            p = ids_path(masks_dir, view.name)
            return load_ids(p) if p.is_file() else None

        try:
            res = train_identity(gaussians, deformation, scene.train, load, config.features, self.temporal,
                                 cache_dir=Path(work_dir) / "pixel_weights", progress=progress)
        except IdentityTrainingError as exc:
            raise MethodError(str(exc)) from None
        if progress and res.classifier.out_features > config.features.n_classes:
            print(f"note: the tracks number ids up to {res.classifier.out_features - 1}: the classifier has "
                  f"{res.classifier.out_features} outputs (method.features.n_classes={config.features.n_classes})",
                  file=sys.stderr)
        with torch.no_grad():
            feats = res.encoder(gaussians.means.detach().cpu(), 0.5).numpy().astype(np.float32)
        info = {
            "timings": {"features_prepare": res.timings["prepare"], "features_train": res.timings["train"],
                        "features_per_step": res.timings["per_step"]},
            "path": res.path_stats,
            "loss_tail": res.history[-5:],
            "tracks": {**(load_tracks_info(masks_dir) if (masks_dir / INFO_FILE).is_file() else {}),
                       "views_without_ids": len(missing)},
            "classifier": pack(res.classifier),
            "n_classes": res.classifier.out_features,
            **({"field": pack(res.encoder)} if self.temporal else {}),
        }
        return feats, info

    # -- the trained model -------------------------------------------------------------
    def _classifier(self, fitted: FittedModel):
        import torch

        from trase_bench_grouping.identity import unpack

        f = fitted.config.features
        n_classes = fitted.stats.get("n_classes", f.n_classes)  # more than the setting where the tracks need them
        return unpack(torch.nn.Linear(f.dim, n_classes), fitted.stats["classifier"])

    def _field(self, fitted: FittedModel):
        from trase_bench_grouping.identity import unpack
        from trase_bench_grouping.train import make_encoder

        return unpack(make_encoder(0, fitted.config.features, True, None), fitted.stats["field"])

    def encodings_at(self, fitted: FittedModel, t: float):
        """[N, D] torch encodings of the gaussians at time t."""
        import torch

        if not self.temporal:
            return torch.from_numpy(np.asarray(fitted.features, np.float32))
        with torch.no_grad():
            return self._field(fitted)(fitted.gaussians.means.detach().float().cpu(), float(t))

    def probabilities_at(self, fitted: FittedModel, t: float):
        """[N, C] class probabilities of the gaussians at time t."""
        import torch

        with torch.no_grad():
            return torch.softmax(self._classifier(fitted)(self.encodings_at(fitted, t)), dim=1)

    def group(self, feats: np.ndarray, config: GroupingSettings, gaussians=None, deformation=None,
              learn_info: dict | None = None) -> FittedModel:
        """Each gaussian's class (argmax; SA4D: at t = 0.5) as its cluster; every gaussian kept."""
        info = dict(learn_info or {})
        if "classifier" not in info:
            raise MethodError(f"{self.name}: the features stage left no classifier (a features cache of another method?)")
        t0 = time.perf_counter()
        stats = {"classifier": info["classifier"], "n_classes": info.get("n_classes", config.features.n_classes), **({"field": info["field"]} if "field" in info else {}),
                 "path": info.get("path", {}), "loss_tail": info.get("loss_tail", []), "tracks": info.get("tracks")}
        fitted = FittedModel(feats, np.zeros(len(feats), np.int64), np.ones(len(feats), bool),
                             dict(info.get("timings", {})), stats, config, gaussians, deformation)
        labels = self.probabilities_at(fitted, 0.5).argmax(dim=1).numpy().astype(np.int64)
        fitted.labels = labels
        fitted.timings["classify"] = time.perf_counter() - t0
        fitted.stats.update(n_gaussians=len(labels), n_clusters=len(np.unique(labels)) if len(labels) else 0,
                            kept_fraction=1.0)
        return fitted

    # -- segment: click -> class -> gaussians ------------------------------------------
    selects_clusters = True
    negative_clicks = True  # a negative click removes a selected class (click_selection)

    def click_logits(self, fitted: FittedModel, scene, prompts):
        """Per click, the classifier's logits [K, C] of the K pixels of its window with enough
        rendered alpha (None: a click on too little alpha)."""
        import torch

        from trase.prompts import geometry_at
        from trase.render import rasterize

        if fitted.gaussians is None:
            raise MethodError(f"{self.name} needs the fitted model's geometry to segment")
        sel, classifier = fitted.config.selection, self._classifier(fitted)
        for c in prompts.clicks:
            cam = click_view(scene, prompts, c).camera
            t = cam.time if c.time is None else float(c.time)
            m, q, s, o = geometry_at(fitted.gaussians, fitted.deformation, t)
            enc = self.encodings_at(fitted, t).to(m.dtype)
            with torch.no_grad():
                r = rasterize(m, q, s, o, cam, features=enc)
            H, W = r.alpha.shape
            col, row = int(np.clip(np.floor(c.u), 0, W - 1)), int(np.clip(np.floor(c.v), 0, H - 1))
            rad = int(sel.click_radius)
            rs, cs = slice(max(row - rad, 0), row + rad + 1), slice(max(col - rad, 0), col + rad + 1)
            ok = r.alpha[rs, cs].reshape(-1) >= float(sel.min_alpha)
            if not bool(ok.any()):
                yield None
                continue
            with torch.no_grad():
                yield classifier(r.features[rs, cs].reshape(-1, enc.shape[1])[ok].float())

    def click_clusters(self, fitted: FittedModel, scene, prompts) -> list[int]:
        """The class the classifier gives the identity rendered under each click (-1: a click
        on too little alpha, or on class 0, "no track")."""
        return [vote(logits) for logits in self.click_logits(fitted, scene, prompts)]

    def click_selection(self, fitted: FittedModel, scene, prompts) -> tuple[list[int], list[int]]:
        """(the classes selected, the class of each click): taken in order as TRASE takes its
        clusters (trase.prompts.select_in_order), each click's window voting among the classes
        allowed. Under ``selection.click_votes`` "any", each click votes among every class and
        benchmark.methods.click_selection's rule combines them."""
        from trase.prompts import select_in_order

        if fitted.config.selection.click_votes == "any":
            return combine_clicks(prompts.clicks, self.click_clusters(fitted, scene, prompts))
        windows = list(self.click_logits(fitted, scene, prompts))
        n_classes = next((w.shape[1] for w in windows if w is not None), 0)
        return select_in_order(list(prompts.clicks), lambda i, exclude: vote(windows[i], exclude),
                               set(range(n_classes)))

    def selected_gaussians(self, fitted: FittedModel, classes: list[int], t: float) -> np.ndarray:
        """[N] bool: gaussians whose probability of a chosen class exceeds the threshold, then
        the convex-hull step (``selection.hull``) for each chosen class."""
        n = fitted.features.shape[0]
        chosen = [k for k in classes if k >= 0]
        if not chosen or n == 0:
            return np.zeros(n, bool)
        s = fitted.config.selection
        probs = self.probabilities_at(fitted, t)
        per_class = (probs[:, chosen] > float(s.prob_threshold)).numpy()  # [N, chosen]
        if s.hull == "none":
            return per_class.any(axis=1)
        # the hull of each chosen class on its own: the public code edits one object at a time,
        # and one hull around objects apart takes in everything between them
        xyz = fitted.gaussians.means.detach().cpu().numpy().astype(np.float64)
        sel = np.zeros(n, bool)
        for col in per_class.T:
            if col.sum() >= 5:
                inside = inside_hull(xyz, col, float(s.hull_outlier_factor))
                col = (col | inside) if s.hull == "union" else (col & inside)
            sel |= col
        return sel

    def render_selection(self, fitted: FittedModel, scene, clusters: list[int]) -> list[np.ndarray]:
        from trase.segment import render_masks

        cams = [v.camera for v in scene.test]
        thr, rule = float(fitted.config.alpha_threshold), str(fitted.config.render_rule)
        if not self.temporal:
            sel = self.selected_gaussians(fitted, clusters, 0.5)
            fitted.stats["selected_gaussians"] = int(sel.sum())
            return render_masks(fitted.gaussians, fitted.deformation, sel, cams, thr, rule)
        out = []
        for cam in cams:  # the field's classes at each view's time
            sel = self.selected_gaussians(fitted, clusters, cam.time)
            out += render_masks(fitted.gaussians, fitted.deformation, sel, [cam], thr, rule)
        return out

    def segment(self, fitted: FittedModel, scene, prompts) -> list[np.ndarray]:
        """One bool [H, W] mask per test view: the gaussians of the classes the clicks chose."""
        classes, per_click = self.click_selection(fitted, scene, prompts)  # negative clicks remove
        fitted.stats["click_clusters"], fitted.stats["selected_clusters"] = per_click, classes
        return self.render_selection(fitted, scene, classes)

    def segment_oracle(self, fitted: FittedModel, scene, gts: list[np.ndarray]):
        """The classes mostly inside the ground truth (each gaussian by its argmax class),
        rendered as segment() renders them: a bound beside the score, never the score. Only
        classes a click can choose: not NO_TRACK, which a click turns into nothing."""
        from benchmark.protocol.oracle import oracle_clusters

        cams = [v.camera for v in scene.test]
        classes = [k for k in oracle_clusters(fitted.gaussians, fitted.deformation, cams, gts, fitted.labels)
                   if k != NO_TRACK]
        return self.render_selection(fitted, scene, list(classes)), list(classes)


class SA4D(GaussianGrouping):
    """SA4D: a temporal identity field (MLP of position and time) classified into track ids."""

    presets = SA4D_PRESETS
    temporal = True


HULL_TOLERANCE = 1e-9  # relative to the coordinates' size: the hull's own vertices count as inside


def inside_hull(points: np.ndarray, chosen: np.ndarray, outlier_factor: float) -> np.ndarray:
    """[N] bool: points inside the convex hull of the chosen points, after dropping chosen
    points outside [Q1 - f IQR, Q3 + f IQR] on any axis (the public code's outlier rule).

    Inside = on the inner side of every facet plane of the hull (``ConvexHull.equations``), one
    matrix product; the public code's Delaunay ``find_simplex`` gives the same set (the tests
    compare them) but walks a tetrahedralisation per point: on a reconstructed scene's wall
    class it took minutes per test view (SA4D hulls again at every view's time)."""
    from scipy.spatial import ConvexHull, QhullError

    pts = points[chosen]
    q1, q3 = np.percentile(pts, 25, axis=0), np.percentile(pts, 75, axis=0)
    iqr = q3 - q1
    ok = ~np.any((pts < q1 - outlier_factor * iqr) | (pts > q3 + outlier_factor * iqr), axis=1)
    pts = pts[ok]
    if len(pts) < 5:
        return np.zeros(len(points), bool)
    try:
        eq = ConvexHull(pts).equations  # [F, 4]: unit outward normal n and offset c, n.x + c <= 0 inside
    except QhullError:  # flat or degenerate: no volume to be inside
        return np.zeros(len(points), bool)
    scale = float(np.abs(pts).max()) or 1.0
    return np.all(points @ eq[:, :3].T + eq[:, 3] <= HULL_TOLERANCE * scale, axis=1)


def vote(logits, exclude=()) -> int:
    """The class most pixels of a click's window vote for (logits [K, C]; each pixel's argmax
    among the classes not in ``exclude``); -1 for no window, no class left, or a vote for
    NO_TRACK ("no track": nothing to select)."""
    import torch

    if logits is None:
        return -1
    allowed = torch.ones(logits.shape[1], dtype=torch.bool)
    allowed[[k for k in exclude if 0 <= k < logits.shape[1]]] = False
    if not bool(allowed.any()):
        return -1
    votes = logits.masked_fill(~allowed, float("-inf")).argmax(dim=1)
    k = int(torch.mode(votes).values) if votes.numel() > 1 else int(votes[0])
    return k if k != NO_TRACK else -1


__all__ = ["NO_TRACK", "SA4D", "GaussianGrouping", "inside_hull", "vote"]
