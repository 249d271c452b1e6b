"""Model folders named by a hub id (``google/owlv2-base-patch16-ensemble``) or a local path.

    folder = model_folder("facebook/sam-vit-base")   # <cache>/weights/hub/facebook--sam-vit-base

A hub id is fetched once: the repository's file list at one commit (with the checksums the hub
publishes: SHA-256 of its large files, the git blob id of the small ones), then each model file
through ``masks.checkpoints.fetch`` (resumed, checked, moved into place only when it matches).
``files.json`` records the commit and every file's checksum; a later use reads only the cache
and checks the files against that record, so a model runs with no network once fetched. Why not
``huggingface_hub.snapshot_download`` alone: it does not check what it wrote against the
published checksums, and a half-written cache must never load.
"""

from __future__ import annotations

import fnmatch
import json
import re
from pathlib import Path

from masks.checkpoints import Checkpoint, fetch, weights_dir
from masks.maskset import MaskError

# what a transformers model folder needs: its config, weights, processor and tokenizer files
MODEL_FILES = ("config.json", "*.safetensors", "preprocessor_config.json", "processor_config.json",
               "tokenizer.json", "tokenizer_config.json", "special_tokens_map.json", "vocab.json",
               "merges.txt")
HUB_ID = re.compile(r"^[A-Za-z0-9][\w.-]*/[\w.-]+$")
DEFAULT_ENDPOINT = "https://huggingface.co"


def model_folder(name: str, cache_dir: Path | None = None, endpoint: str | None = None,
                 progress: bool = True) -> Path:
    """A local folder with the model ``name``: a folder as given, else a hub id fetched once."""
    path = Path(name).expanduser()
    if path.exists():
        if not (path / "config.json").is_file():
            raise MaskError(f"{path}: not a model folder (no config.json)")
        return path
    if not HUB_ID.match(name):
        raise MaskError(f"{name}: no such folder, and not a hub id (owner/name)")
    return hub_folder(name, cache_dir or weights_dir() / "hub", endpoint, progress)


def hub_folder(repo_id: str, cache_dir: Path, endpoint: str | None = None, progress: bool = True) -> Path:
    """``repo_id``'s model files in ``cache_dir/<owner>--<name>``, fetched and checked once."""
    folder = Path(cache_dir) / repo_id.replace("/", "--")
    record = folder / "files.json"
    if record.is_file():
        files = _read_record(record)
    else:
        files = _published_files(repo_id, endpoint or DEFAULT_ENDPOINT)
    for ck in files:
        fetch(ck, folder, progress)  # checks a file in place, fetches a missing one
    if not record.is_file():
        record.write_text(json.dumps([{"url": c.url, "checksum": c.sha256, "digest": c.digest, "name": c.name}
                                      for c in files], indent=1))
    return folder


def _published_files(repo_id: str, endpoint: str) -> list[Checkpoint]:
    """The model files of ``repo_id`` at its current commit, each with its published checksum."""
    try:
        from huggingface_hub import HfApi, hf_hub_url
    except ImportError:
        raise MaskError("text prompts need the 'text' extra: pip install 'trase-bench[text]'") from None
    api = HfApi(endpoint=endpoint)
    try:
        commit = api.model_info(repo_id).sha
        tree = [f for f in api.list_repo_tree(repo_id, revision=commit, recursive=True) if hasattr(f, "blob_id")]
    except Exception as exc:  # noqa: BLE001 - the hub client raises many kinds; each is one line here
        raise MaskError(f"{endpoint}/{repo_id}: cannot list the model's files ({type(exc).__name__}: "
                        f"{str(exc).splitlines()[0] if str(exc) else 'no detail'}); with no network, download "
                        "the folder elsewhere and pass its path") from None
    wanted = [f for f in tree if "/" not in f.path and any(fnmatch.fnmatch(f.path, p) for p in MODEL_FILES)]
    if not any(f.path == "config.json" for f in wanted):
        raise MaskError(f"{endpoint}/{repo_id}: the repository has no config.json at its top level")
    return [Checkpoint(hf_hub_url(repo_id, f.path, revision=commit, endpoint=endpoint),
                       f.lfs.sha256 if f.lfs is not None else f.blob_id,
                       "sha256" if f.lfs is not None else "git-sha1", f.path) for f in wanted]


def _read_record(path: Path) -> list[Checkpoint]:
    try:
        rows = json.loads(path.read_text())
        return [Checkpoint(r["url"], r["checksum"], r["digest"], r["name"]) for r in rows]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise MaskError(f"{path}: unreadable record of a fetched model ({exc}); delete the folder to fetch "
                        "it again") from None


__all__ = ["DEFAULT_ENDPOINT", "MODEL_FILES", "hub_folder", "model_folder"]
