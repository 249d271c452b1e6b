"""K=16 nearest neighbours of every gaussian (the smoothing graph), several ways, side by side.

What trase/smoothing.py uses: ``knn_indices`` = scipy cKDTree on float64, one query thread,
then a fix-up that puts each point first in its own row. Alternatives: the same tree queried
on all cores (``workers=-1``), in chunks (bounded memory for the distance array), and
scikit-learn's NearestNeighbors (kd_tree, n_jobs=-1). Each is timed build + query, median of
repeats. Correctness: for a random set of query rows the exact neighbours are found by brute
force (torch, chunked); a method's row "agrees" when its neighbour set equals the exact one,
or differs only by points at exactly the K-th distance (a tie). The per-step smoothing itself
(mean of 8 of 16 normalised 32-d neighbour features, forward + backward) is timed as well.

Positions: a clumpy cloud like a reconstruction's (points on random sphere shells and in
anisotropic blobs), float32 as trained gaussians are.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
import torch

from benchmark.perf.common import fmt, load_average, ratio, table, time_repeats, versions

K = 16
QUICK = {"sizes": [5_000], "repeats": 2, "check_rows": 300}
DEFAULT = {"sizes": [100_000, 300_000, 1_000_000], "repeats": 3, "check_rows": 2000}
CHUNK = 131_072


def make_points(n: int, seed: int = 0) -> np.ndarray:
    """[n, 3] float32 clumpy cloud: half on 40 sphere shells, half in 40 anisotropic blobs."""
    rng = np.random.default_rng(seed)
    n_shell = n // 2
    centres = rng.uniform(-1, 1, (40, 3))
    radii = rng.uniform(0.05, 0.4, 40)
    which = rng.integers(0, 40, n_shell)
    d = rng.standard_normal((n_shell, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True) + 1e-12
    shell = centres[which] + d * radii[which, None] * (1 + 0.01 * rng.standard_normal((n_shell, 1)))
    n_blob = n - n_shell
    bc = rng.uniform(-1, 1, (40, 3))
    axes = rng.uniform(0.01, 0.2, (40, 3))
    which = rng.integers(0, 40, n_blob)
    blob = bc[which] + rng.standard_normal((n_blob, 3)) * axes[which]
    pts = np.concatenate([shell, blob]).astype(np.float32)
    return pts[rng.permutation(n)]


# -- the alternatives: [N, 3] -> [N, K] int64 neighbour ids ------------------------------------
def knn_trase(pts: np.ndarray) -> np.ndarray:
    from trase.smoothing import knn_indices

    return knn_indices(pts, K).numpy()


def knn_ckdtree_all_cores(pts: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    return cKDTree(pts).query(pts, k=K, workers=-1)[1].astype(np.int64)


def knn_ckdtree_chunked(pts: np.ndarray) -> np.ndarray:
    """Same tree, queried CHUNK rows at a time (peak memory of the distances bounded)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(pts)
    out = np.empty((pts.shape[0], K), np.int64)
    for s in range(0, pts.shape[0], CHUNK):
        out[s:s + CHUNK] = tree.query(pts[s:s + CHUNK], k=K, workers=-1)[1]
    return out


def knn_sklearn(pts: np.ndarray) -> np.ndarray:
    from sklearn.neighbors import NearestNeighbors

    nn = NearestNeighbors(n_neighbors=K, algorithm="kd_tree", n_jobs=-1).fit(pts)
    return nn.kneighbors(pts, return_distance=False).astype(np.int64)


METHODS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "trase.smoothing.knn_indices (cKDTree, 1 thread)": knn_trase,
    "cKDTree workers=-1": knn_ckdtree_all_cores,
    f"cKDTree workers=-1, chunks of {CHUNK}": knn_ckdtree_chunked,
    "sklearn NearestNeighbors kd_tree n_jobs=-1": knn_sklearn,
}
REFERENCE = "trase.smoothing.knn_indices (cKDTree, 1 thread)"


def exact_knn(pts: np.ndarray, rows: np.ndarray, chunk: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Brute force: rows [R] -> (ids [R, K], squared distances [R, K]) in float64.

    Candidates from |q|^2 + |p|^2 - 2 q.p over all points ([chunk, N] at a time, bounded
    memory); the returned distances are recomputed directly from the coordinates."""
    p = torch.from_numpy(pts.astype(np.float64))  # [N, 3]
    pn = (p * p).sum(1)  # [N]
    ids, dists = [], []
    for s in range(0, len(rows), chunk):
        q = p[torch.from_numpy(rows[s:s + chunk])]  # [c, 3]
        d2 = (q * q).sum(1)[:, None] + pn[None, :] - 2.0 * q @ p.T  # [c, N]
        i = torch.topk(d2, K, dim=1, largest=False).indices  # [c, K]
        exact = ((p[i] - q[:, None, :]) ** 2).sum(-1)  # [c, K]
        exact, order = torch.sort(exact, dim=1)
        ids.append(torch.gather(i, 1, order).numpy())
        dists.append(exact.numpy())
    return np.concatenate(ids), np.concatenate(dists)


def agreement(pts: np.ndarray, got: np.ndarray, rows: np.ndarray, ex_ids: np.ndarray,
              ex_d2: np.ndarray) -> dict:
    """Fraction of checked rows whose neighbour set equals the exact one (up to K-th-distance
    ties), fraction exactly equal, and whether the point itself is in its own row."""
    p = pts.astype(np.float64)
    exact_equal = tie_equal = self_in = 0
    for r, row in enumerate(rows):
        g = got[row]
        self_in += int(row in g)
        if set(g.tolist()) == set(ex_ids[r].tolist()):
            exact_equal += 1
            tie_equal += 1
            continue
        gd = np.sort(((p[g] - p[row]) ** 2).sum(1))
        if np.allclose(gd, ex_d2[r], rtol=1e-9, atol=1e-12):
            tie_equal += 1
    n = max(len(rows), 1)
    return {"rows_checked": len(rows), "equal_sets": exact_equal / n, "equal_up_to_ties": tie_equal / n,
            "self_included": self_in / n}


def smoothing_step(knn: np.ndarray, dim: int = 32, seed: int = 0) -> Callable[[], float]:
    """One training step's smoothing: features [N, dim] -> mean of 8 of 16 slots, backward."""
    from trase.smoothing import smooth_features

    g = torch.Generator().manual_seed(seed)
    feats = torch.nn.Parameter(torch.randn(knn.shape[0], dim, generator=g))
    idx = torch.from_numpy(knn)

    def step() -> float:
        feats.grad = None
        out = smooth_features(feats, idx, 8, g)
        out.sum().backward()
        return float(out.shape[0])

    return step


def run(quick: bool = False, echo: Callable[[str], None] = print) -> dict:
    cfg = QUICK if quick else DEFAULT
    reps = cfg["repeats"]
    echo(f"KNN K={K} on clumpy float32 positions; build + query wall time, median of {reps} "
         f"(spread = max - min); agreement with brute force on {cfg['check_rows']} random rows")
    results = []
    rows_txt = []
    for n in cfg["sizes"]:
        pts = make_points(n)
        rng = np.random.default_rng(1)
        rows = np.sort(rng.choice(n, size=min(cfg["check_rows"], n), replace=False))
        ex_ids, ex_d2 = exact_knn(pts, rows)
        entry = {"n": n, "methods": {}}
        got_ref = None
        for name, fn in METHODS.items():
            t, got = time_repeats(functools.partial(fn, pts), reps)
            m = {"seconds": t, **agreement(pts, got, rows, ex_ids, ex_d2)}
            if name == REFERENCE:
                got_ref = got
            entry["methods"][name] = m
        for name, m in entry["methods"].items():
            m["ratio_to_trase"] = ratio(m["seconds"], entry["methods"][REFERENCE]["seconds"])
            rows_txt.append([f"{n // 1000}k  {name}", fmt(m["seconds"]), f"{m['ratio_to_trase']:.2f}x",
                             f"{m['equal_sets']:.4f}", f"{m['equal_up_to_ties']:.4f}", f"{m['self_included']:.3f}"])
        t_smooth, _ = time_repeats(smoothing_step(got_ref), reps, warmup=1)
        entry["smoothing_step_seconds"] = t_smooth
        rows_txt.append([f"{n // 1000}k  smoothing step (8 of 16 slots, D=32, fwd+bwd)", fmt(t_smooth), "", "", "", ""])
        results.append(entry)
    echo(table(rows_txt, ["N  method", "time", "vs trase", "equal sets", "equal up to ties", "self in row"]))
    return {
        "description": __doc__.strip().splitlines()[0],
        "quick": quick,
        "settings": {**cfg, "k": K, "chunk": CHUNK, "torch_threads": torch.get_num_threads()},
        "versions": versions("scipy", "sklearn", "numpy", "torch"),
        "sizes": results,
        "load_average_end": load_average(),
    }
