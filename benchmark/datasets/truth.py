"""What a synthetic scene knows beyond its images: ``synthetic/manifest.json``, read once.

The generator (benchmark.datasets.synthetic.generate) writes the manifest with
``write_manifest``; the loader reads it with ``read_truth`` into ``Scene.truth``, and every user
(masks from instance maps, ground-truth geometry, the ceiling, the results' scene block) takes
the typed fields from there. Real scenes have no truth (``Scene.truth is None``).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from benchmark.datasets.errors import DatasetError

MANIFEST = Path("synthetic") / "manifest.json"  # relative to the scene directory
# the manifest's facts that say which synthetic scene a result was measured on
SCENE_INFO_KEYS = ("generator_version", "seed", "size", "difficulty", "frames_per_camera", "motion_span")


@dataclasses.dataclass(frozen=True)
class SceneObject:
    id: int  # instance id in the instance maps
    name: str
    of_interest: bool
    motion: str = ""  # "static", "rigid" or "deforming" ("" where the manifest does not say)


@dataclasses.dataclass(frozen=True)
class SceneTruth:
    manifest_path: Path
    objects: tuple[SceneObject, ...]  # every instance id (the room as floor and walls)
    instance_maps: dict[str, Path]  # view name -> 16-bit instance id PNG
    geometry_path: Path  # ground-truth gaussians with tabulated motion (trase.checkpoint)
    info: dict  # SCENE_INFO_KEYS -> value (None where the manifest lacks it)
    name: str = ""  # the sequence name the generator gave it ("synthetic-tiny"; a data root may call it otherwise)

    @property
    def interest_ids(self) -> list[int]:
        """Instance ids of the objects of interest (the ground-truth masks' objects)."""
        return [o.id for o in self.objects if o.of_interest]

    @property
    def mover_ids(self) -> list[int]:
        """Instance ids of the moving objects that are not of interest (occluders that pass in
        front of the objects the ground truth masks)."""
        return [o.id for o in self.objects if not o.of_interest and o.motion not in ("", "static")]

    @property
    def n_ids(self) -> int:
        """One more than the largest instance id (0 is the background)."""
        return max([o.id for o in self.objects] + [0]) + 1


def _fail(path: Path, problem: str) -> DatasetError:
    return DatasetError(f"{path}: {problem}")


def read_truth(path: str | Path) -> SceneTruth:
    """Parse a synthetic manifest; every field is optional (the user that needs one says so),
    but a field that is present must have its type."""
    path = Path(path)
    try:
        man = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise _fail(path, f"cannot read the synthetic manifest ({type(exc).__name__}: {exc})") from None
    if not isinstance(man, dict):
        raise _fail(path, "the synthetic manifest is not a JSON object")
    try:
        wanted = set(man.get("objects_of_interest", []))
        objects = tuple(SceneObject(int(o["id"]), str(o["name"]), o["name"] in wanted, str(o.get("motion", "")))
                        for o in man.get("objects", []))
        maps = {str(k): path.parent / str(v) for k, v in dict(man.get("instances", {})).items()}
    except (KeyError, TypeError, ValueError) as exc:
        raise _fail(path, f"synthetic manifest: malformed objects or instances ({type(exc).__name__}: {exc})") from None
    return SceneTruth(path, objects, maps, path.parent / str(man.get("geometry", "geometry.npz")),
                      {k: man.get(k) for k in SCENE_INFO_KEYS}, str(man.get("sequence", "")))


def find_truth(scene_dir: Path) -> SceneTruth | None:
    """The scene's truth, or None where the scene has no synthetic manifest (real data)."""
    path = Path(scene_dir) / MANIFEST
    return read_truth(path) if path.is_file() else None


def write_manifest(scene_dir: Path, manifest: dict) -> Path:
    """Write the generator's manifest (its fields as ``read_truth`` reads them, plus the
    generator's own notes) -> its path."""
    path = Path(scene_dir) / MANIFEST
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(manifest, indent=1) + "\n")
    return path


__all__ = ["MANIFEST", "SCENE_INFO_KEYS", "SceneObject", "SceneTruth", "find_truth", "read_truth", "write_manifest"]
