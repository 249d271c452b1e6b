"""Model weights fetched once into a cache, checked against their published SHA-256.

    path = sam_checkpoint("vit_b")        # ~/.cache/trase-bench/weights/sam_vit_b_01ec64.pth

Why a fetcher of its own: the official SAM checkpoints are plain HTTPS files (no hub, no
package) of 375 MB to 2.6 GB, where a broken connection should resume, not restart, and a file
that is not the published one must never be used. ``fetch`` streams into ``<name>.part``,
resumes with an HTTP Range request where the server allows it (a server that ignores the range
gets a fresh download), shows a progress bar, checks the SHA-256 and only then moves the file
into place; a file already in place is checked once more before use. Every failure is one line
naming the URL or the file, and says how to continue without the network (a local checkpoint).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import urllib.error
import urllib.request
from pathlib import Path

from masks.generators.base import MaskError

CHUNK = 1 << 20


@dataclasses.dataclass(frozen=True)
class Checkpoint:
    url: str
    sha256: str  # of the whole file, as published with it (see ``digest``)
    # "sha256", or "git-sha1": the git blob id a model hub publishes for its small files
    digest: str = "sha256"
    name: str = ""  # the file's name in the cache (default: the URL's last part)

    @property
    def filename(self) -> str:
        return self.name or self.url.rsplit("/", 1)[-1]

    @property
    def digest_name(self) -> str:
        return {"sha256": "SHA-256", "git-sha1": "git blob SHA-1"}[self.digest]

    def checksum(self, path: Path) -> str:
        """``path``'s checksum of this checkpoint's kind."""
        return git_blob_sha1(path) if self.digest == "git-sha1" else sha256_of(path)


# The official segment-anything checkpoints (facebookresearch/segment-anything README) and their
# SHA-256, as recorded by the projects that verify them (vit_b 375,042,383 bytes; vit_h
# 2,564,550,879 bytes).
SAM_CHECKPOINTS = {
    "vit_b": Checkpoint("https://dl.fbaipublicfiles.com/segment_anything/sam_vit_b_01ec64.pth",
                        "ec2df62732614e57411cdcf32a23ffdf28910380d03139ee0f4fcbe91eb8c912"),
    "vit_l": Checkpoint("https://dl.fbaipublicfiles.com/segment_anything/sam_vit_l_0b3195.pth",
                        "3adcc4315b642a4d2101128f611684e8734c41232a17c648ed1693702a49a622"),
    "vit_h": Checkpoint("https://dl.fbaipublicfiles.com/segment_anything/sam_vit_h_4b8939.pth",
                        "a7bf3b02f3ebf1267aba913ff637d9a2d5c33d3173bb679e46d9f338c26f262e"),
}


def weights_dir() -> Path:
    """$TRASE_BENCH_CACHE/weights, else ~/.cache/trase-bench/weights."""
    import cachedir

    return cachedir.subfolder("weights")


def sha256_of(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def git_blob_sha1(path: Path) -> str:
    """The git blob id of ``path`` (SHA-1 of ``blob <size>\\0`` and the bytes)."""
    h = hashlib.sha1(f"blob {Path(path).stat().st_size}\0".encode())
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def sam_checkpoint(model: str, cache_dir: Path | None = None, progress: bool = True) -> Path:
    """The official SAM checkpoint of ``model`` (vit_b, vit_l, vit_h), fetched on first use."""
    if model not in SAM_CHECKPOINTS:
        raise MaskError(f"masks.model={model}: choose {', '.join(SAM_CHECKPOINTS)}")
    return fetch(SAM_CHECKPOINTS[model], cache_dir or weights_dir(), progress)


def fetch(ck: Checkpoint, cache_dir: Path, progress: bool = True, timeout: float = 60.0) -> Path:
    """``ck`` in ``cache_dir`` (downloaded, resumed or reused), its SHA-256 checked."""
    dest = Path(cache_dir) / ck.filename
    if dest.is_file():
        have = ck.checksum(dest)
        if have == ck.sha256:
            return dest
        raise MaskError(f"{dest}: {ck.digest_name} {have[:12]}... is not the published {ck.sha256[:12]}...; "
                        "delete it to download it again")
    dest.parent.mkdir(parents=True, exist_ok=True)
    part = dest.with_name(dest.name + ".part")
    _download(ck.url, part, progress, timeout)
    got = ck.checksum(part)
    if got != ck.sha256:
        part.unlink(missing_ok=True)
        raise MaskError(f"{ck.url}: downloaded file has {ck.digest_name} {got[:12]}..., not the published "
                        f"{ck.sha256[:12]}... (deleted; try again, or pass a checkpoint you have)")
    os.replace(part, dest)
    return dest


def _download(url: str, part: Path, progress: bool, timeout: float) -> None:
    """Stream ``url`` into ``part``, continuing what is there when the server honours a range."""
    have = part.stat().st_size if part.is_file() else 0
    req = urllib.request.Request(url, headers={"Range": f"bytes={have}-"} if have else {})
    try:
        resp = urllib.request.urlopen(req, timeout=timeout)
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and have:  # the range starts at the end: the part is complete
            return
        raise MaskError(f"{url}: HTTP {exc.code} {exc.reason} (download it yourself and set masks.checkpoint=PATH)") from None
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise MaskError(f"{url}: cannot download ({reason}); with no network, download it elsewhere and set "
                        "masks.checkpoint=PATH") from None
    with resp:
        resumed = have and resp.status == 206
        total = resp.headers.get("Content-Length")
        total = int(total) + (have if resumed else 0) if total is not None else None
        bar = _Bar(progress, part.name.removesuffix(".part"), total, have if resumed else 0)
        try:
            with open(part, "ab" if resumed else "wb") as f:
                while True:
                    try:
                        block = resp.read(CHUNK)
                    except (OSError, urllib.error.URLError) as exc:
                        raise MaskError(f"{url}: connection broke after {f.tell()} bytes ({exc}); run again "
                                        "to resume") from None
                    if not block:
                        break
                    f.write(block)
                    bar.advance(len(block))
                got = f.tell()
        finally:
            bar.close()
    if total is not None and got != total:
        raise MaskError(f"{url}: connection ended after {got} of {total} bytes; run again to resume")


class _Bar:
    """rich download bar (bytes, speed), silent when disabled."""

    def __init__(self, enabled: bool, name: str, total: int | None, done: int) -> None:
        self.p = None
        if enabled:
            from rich.progress import (
                BarColumn,
                DownloadColumn,
                Progress,
                TextColumn,
                TransferSpeedColumn,
            )

            self.p = Progress(TextColumn(f"download {name}"), BarColumn(), DownloadColumn(), TransferSpeedColumn())
            self.p.start()
            self.task = self.p.add_task("download", total=total, completed=done)

    def advance(self, n: int) -> None:
        if self.p is not None:
            self.p.advance(self.task, n)

    def close(self) -> None:
        if self.p is not None:
            self.p.stop()


__all__ = ["SAM_CHECKPOINTS", "Checkpoint", "fetch", "git_blob_sha1", "sam_checkpoint", "sha256_of", "weights_dir"]
