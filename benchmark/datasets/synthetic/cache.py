"""The embedded default: real data when it is there, else a cached synthetic scene.

Cache layout: ``<cache>/<dataset>/v<GENERATOR_VERSION>/<sequence>/`` with ``<cache>`` =
``$TRASE_BENCH_CACHE/synthetic`` (default ``~/.cache/trase-bench/synthetic``): a new generator version never
reuses (nor deletes, under a running job) the scenes of an older one. A scene is generated into a temporary sibling directory
and renamed into place when complete, so an interrupted run never leaves a half scene that a
later run would trust; concurrent generators race harmlessly (the loser's copy is removed).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
from pathlib import Path

from benchmark.background_compile import kernels_compiled_meanwhile

from .generate import (
    GENERATOR_VERSION,
    SyntheticError,
    _check_args,
    generate,
    parse_sequence_name,
    sequence_name,
)


def default_cache_dir() -> Path:
    import cachedir

    return cachedir.subfolder("synthetic")


def _is_complete(scene_dir: Path) -> bool:
    return (scene_dir / "synthetic" / "manifest.json").is_file()


def synthetic_copy(root: Path, dataset: str, sequence: str) -> Path | None:
    """``<root>/<dataset>/<sequence>`` where it holds a whole synthetic scene (one that
    ``trase-bench synth`` wrote there), else None: a run uses it in place of the built-in one."""
    d = Path(root) / dataset / sequence
    return d if _is_complete(d) else None


def _check_version(scene_dir: Path) -> None:
    """A cached scene written by another generator version is an error, never silently used."""
    import json

    path = scene_dir / "synthetic" / "manifest.json"
    try:
        version = json.loads(path.read_text()).get("generator_version")
    except (OSError, ValueError) as exc:
        raise SyntheticError(f"{path}: unreadable synthetic manifest ({exc}); delete {scene_dir} to regenerate") from None
    if version != GENERATOR_VERSION:
        raise SyntheticError(f"{path}: scene from generator version {version}, this is version "
                             f"{GENERATOR_VERSION}; delete {scene_dir} to regenerate")


def ensure_synthetic(dataset: str, size: str = "small", seed: int = 0,
                     cache_dir: Path | str | None = None, progress=None, difficulty: str = "standard",
                     create: bool = True, precompile: bool = False) -> Path:
    """The cached synthetic scene of ``dataset`` (generated on first use, with a notice;
    ``create=False``: an error instead, for plans that must not write anything).
    ``precompile``: compile trase's kernels in another process while the scene is generated
    (``benchmark.background_compile``; what a run does, since it needs them next).

    Seed 0 lives at ``<cache>/<dataset>/v<version>/<sequence>``; another seed at
    ``<sequence>-seed<N>``.
    """
    _check_args(dataset, size, difficulty)
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    name = sequence_name(size, difficulty) + (f"-seed{seed}" if seed != 0 else "")
    final = cache / dataset / f"v{GENERATOR_VERSION}" / name
    if _is_complete(final):
        _check_version(final)
        return final
    if final.exists():
        raise SyntheticError(f"{final}: incomplete synthetic scene (no synthetic/manifest.json); delete it to regenerate")
    if not create:
        raise SyntheticError(f"{final}: synthetic scene not generated yet (the first run generates it)")
    final.parent.mkdir(parents=True, exist_ok=True)
    print(f"trase-bench: no real {dataset} data found; generating the synthetic scene "
          f"(size {size}, {difficulty}, seed {seed}) into {final}", file=sys.stderr)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.tmp-", dir=final.parent))
    try:
        scene_tmp = tmp / name  # the scene folder's name is its sequence name
        with kernels_compiled_meanwhile() if precompile else contextlib.nullcontext():
            generate(dataset, scene_tmp, seed=seed, size=size, progress=progress, difficulty=difficulty)
        try:
            os.rename(scene_tmp, final)
        except OSError:
            if not _is_complete(final):
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return final


def find_or_generate(dataset: str, sequence: str | None = None,
                     data_root: Path | str | None = None,
                     cache_dir: Path | str | None = None, create: bool = True,
                     precompile: bool = False) -> tuple[Path, str]:
    """(scene_dir, variant) for ``dataset``/``sequence``: real data wins, else synthetic.

    Real data is looked up at ``<root>/<dataset>/<sequence>/`` (and the publishers' other
    layouts, see ``benchmark.datasets.find_scene_dir``) under ``data_root`` or ``$TRASE_DATA``.
    ``sequence`` None or a synthetic name ("synthetic", "synthetic-medium", "synthetic-hard",
    ...; ``generate.sequence_name``) uses the synthetic scene when no real scene of that name
    exists; a real sequence name that is missing is
    an error listing where it looked. ``precompile``: as for ``ensure_synthetic``.
    """
    from benchmark.datasets import data_root as real_root
    from benchmark.datasets import find_scene_dir, get_dataset

    spec = get_dataset(dataset)
    root = real_root(data_root)
    roots = [] if root is None else [root]
    seq = sequence if sequence is not None else sequence_name("small")
    synthetic = parse_sequence_name(seq)
    if synthetic is None:
        seq = spec.resolve_sequence(seq)
        for root in roots:
            found = find_scene_dir(spec.key, seq, root)
            if found is not None:
                return found, "real"
        where = ", ".join(f"{r / spec.key / seq} (and {r / spec.display_name}/, nested folders)" for r in roots) \
            or "nowhere: no --data-root given and TRASE_DATA is not set"
        raise SyntheticError(
            f"{spec.key}: real sequence {seq!r} not found (looked in: {where}); pass --data-root "
            f"or set TRASE_DATA, or use the synthetic default (sequence 'synthetic')"
        )
    for root in roots:  # a real copy of a synthetic scene under the data root is used as is
        d = synthetic_copy(root, spec.key, seq)
        if d is not None:
            return d, "synthetic"
    size, difficulty = synthetic
    return ensure_synthetic(spec.key, size=size, cache_dir=cache_dir, difficulty=difficulty, create=create,
                            precompile=precompile), \
        "synthetic"
