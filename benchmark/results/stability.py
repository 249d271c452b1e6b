"""How much a run's clustering changes with its seed: adjusted Rand index between seeds.

Two comparisons, from what every run leaves in its directory (``clusters/``):

* gaussians: the labels of the same gaussians (``labels.npy``), when two runs share their
  geometry (same checksum: ground-truth geometry, or one reconstruction reused);
* pixels: the cluster rendered most at each pixel of the shown test views
  (``ids_<frame>.png``, 16-bit, 0 = no surface), over the pixels where both runs have a
  surface. Works across different reconstructions (the gaussians differ, the views do not).

ARI is 1 for the same partition up to renaming, about 0 for unrelated ones (sklearn's
``adjusted_rand_score``).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

LABELS_FILE = "labels.npy"
ID_PREFIX = "ids_"
CHUNK = 32  # clusters rendered per pass when finding each pixel's cluster


def cluster_id_map(gaussians, deformation, labels: np.ndarray, camera, min_alpha: float = 0.5) -> np.ndarray:
    """[H, W] int64: the cluster with the largest rendered weight at each pixel, -1 where the
    rendered alpha is below ``min_alpha`` (no surface). Clusters are rendered as one-hot
    features, CHUNK at a time."""
    import torch

    from trase.deformation import deformed
    from trase.render import rasterize

    labels = np.asarray(labels, np.int64)
    n_clusters = int(labels.max()) + 1 if labels.size else 0
    if n_clusters == 0:
        return np.full((camera.height, camera.width), -1, np.int64)
    with torch.no_grad():
        means, quats, scales = deformed(gaussians, deformation, camera.time)
        opac = gaussians.opacities.detach()
        lab = torch.as_tensor(labels)
        best = torch.full((camera.height, camera.width), -1.0, dtype=means.dtype)
        ids = torch.full((camera.height, camera.width), -1, dtype=torch.int64)
        alpha = None
        for start in range(0, n_clusters, CHUNK):
            k = min(CHUNK, n_clusters - start)
            onehot = (lab[:, None] == torch.arange(start, start + k)[None, :]).to(means.dtype)
            out = rasterize(means, quats, scales, opac, camera, features=onehot)
            alpha = out.alpha if alpha is None else alpha
            w, arg = out.features.max(dim=-1)
            better = w > best
            best = torch.where(better, w, best)
            ids = torch.where(better, arg + start, ids)
        ids[alpha < min_alpha] = -1
    return ids.numpy()


def save_cluster_maps(directory: Path, fitted, cameras: dict[str, object]) -> None:
    """``labels.npy`` and one ``ids_<frame>.png`` per named camera into ``directory``."""
    import cv2

    directory.mkdir(parents=True, exist_ok=True)
    np.save(directory / LABELS_FILE, np.asarray(fitted.labels, np.int32))
    for name, cam in cameras.items():
        ids = cluster_id_map(fitted.gaussians, fitted.deformation, fitted.labels, cam)
        if ids.max() >= 65535:
            raise ValueError(f"{ids.max() + 1} clusters do not fit a 16-bit id map")
        cv2.imwrite(str(directory / f"{ID_PREFIX}{name}.png"), (ids + 1).astype(np.uint16))


def _read_ids(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: unreadable cluster id map")
    return img.astype(np.int64) - 1


def pixel_ari(dir_a: Path, dir_b: Path) -> float | None:
    """ARI over the pixels with a surface in both runs' id maps of the same frames (None when
    they share no frame or no such pixel)."""
    from sklearn.metrics import adjusted_rand_score

    a_maps = {p.name: p for p in Path(dir_a).glob(f"{ID_PREFIX}*.png")}
    xs, ys = [], []
    for name, pa in sorted(a_maps.items()):
        pb = Path(dir_b) / name
        if not pb.is_file():
            continue
        a, b = _read_ids(pa), _read_ids(pb)
        if a.shape != b.shape:
            continue
        both = (a >= 0) & (b >= 0)
        xs.append(a[both])
        ys.append(b[both])
    if not xs or not sum(x.size for x in xs):
        return None
    return float(adjusted_rand_score(np.concatenate(xs), np.concatenate(ys)))


def gaussian_ari(dir_a: Path, dir_b: Path) -> float | None:
    """ARI of the two runs' per-gaussian labels (None when the counts differ)."""
    from sklearn.metrics import adjusted_rand_score

    a, b = np.load(Path(dir_a) / LABELS_FILE), np.load(Path(dir_b) / LABELS_FILE)
    return float(adjusted_rand_score(a, b)) if a.shape == b.shape else None


def seed_agreement(records: list[dict]) -> dict | None:
    """Pairwise ARI between runs of one config with different seeds (``records``: results
    with ``_dir``) -> {pairs: [...], pixel_mean, gaussian_mean}; None for fewer than two."""
    runs = sorted(records, key=lambda r: r["run"]["seed"])
    if len(runs) < 2:
        return None
    pairs = []
    for a, b in itertools.combinations(runs, 2):
        da, db = Path(a["_dir"]) / "clusters", Path(b["_dir"]) / "clusters"
        if not (da / LABELS_FILE).is_file() or not (db / LABELS_FILE).is_file():
            continue
        same_geometry = a.get("geometry_checksum") is not None and \
            a.get("geometry_checksum") == b.get("geometry_checksum")
        pairs.append({"seeds": [a["run"]["seed"], b["run"]["seed"]], "pixel_ari": pixel_ari(da, db),
                      "gaussian_ari": gaussian_ari(da, db) if same_geometry else None})
    if not pairs:
        return None
    return {"pairs": pairs, "pixel_ari": _mean(p["pixel_ari"] for p in pairs),
            "gaussian_ari": _mean(p["gaussian_ari"] for p in pairs)}


def _mean(values) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def geometry_checksum(gaussians) -> str:
    """Content hash of the gaussians (means, scales, rotations, opacities): equal for the same
    geometry, whatever stage or seed produced it."""
    import hashlib

    h = hashlib.sha256()
    for t in (gaussians.means, gaussians.log_scales, gaussians.quats, gaussians.opacity_logits):
        h.update(t.detach().cpu().float().numpy().tobytes())
    return h.hexdigest()[:16]


def seed_summary(records: list[dict]) -> dict:
    """Mean and sample std (ddof 1) over the seeds of one config of the official mIoU, the
    oracle's and the geometry ceiling's mIoU, the click sets' median and worst, the corrective
    protocol's mIoU@1, NoC@85 and NoC@90, and the clustering agreement (``seed_agreement``)."""
    def stats(values) -> dict | None:
        v = np.array([x for x in values if x is not None], dtype=float)
        if not v.size:
            return None
        return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size > 1 else None, "n": int(v.size)}

    def get(r, *path):
        for p in path:
            r = (r or {}).get(p) if isinstance(r, dict) else None
        return r

    return {
        "seeds": [r["run"]["seed"] for r in records],
        "miou": stats(get(r, "metrics", "official", "miou") for r in records),
        "oracle": stats(get(r, "oracle", "miou") for r in records),
        "ceiling": stats(get(r, "ceiling", "miou") for r in records),
        "click_sets_median": stats(get(r, "click_sets", "median") for r in records),
        "click_sets_worst": stats(get(r, "click_sets", "worst") for r in records),
        # the corrective protocol (benchmark.pipeline.corrective): the first clicks' score and the
        # clicks needed to reach mIoU 0.85 / 0.90; None for runs of the first clicks alone
        "miou_at_1": stats((get(r, "corrective", "curve") or [{}])[0].get("miou") for r in records),
        "noc85": stats(get(r, "corrective", "noc@85") for r in records),
        "noc90": stats(get(r, "corrective", "noc@90") for r in records),
        "agreement": seed_agreement(records),
    }


def format_summary(s: dict) -> str:
    """One line: 'seeds 0,1,2: mIoU 0.9012 ± 0.0100, oracle ..., pixel ARI 0.91'."""
    def one(name, st):
        if not st:
            return None
        return f"{name} {st['mean']:.4f}" + (f" ± {st['std']:.4f}" if st["std"] is not None else "")

    parts = [one("mIoU", s["miou"]), one("oracle", s["oracle"]), one("ceiling", s["ceiling"]),
             one("click-set median", s["click_sets_median"]), one("click-set worst", s["click_sets_worst"])]
    ag = s.get("agreement") or {}
    if ag.get("pixel_ari") is not None:
        parts.append(f"pixel ARI {ag['pixel_ari']:.3f}")
    if ag.get("gaussian_ari") is not None:
        parts.append(f"gaussian ARI {ag['gaussian_ari']:.3f}")
    return f"seeds {','.join(map(str, s['seeds']))}: " + ", ".join(p for p in parts if p)
