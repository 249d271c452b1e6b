"""Mask files: our bit-packed format and the paper's torch/bitarray format (COCO RLE:
``masks.coco``; bytes per representation: ``masks.compression``).

Our format (``*.masks``), little-endian, no pickle::

    0   8 bytes  magic  b"\\x89TRMASK\\n"
    8   uint32   L = length of the JSON header
    12  L bytes  JSON header: format_version, n, height, width, generator, info, has_score,
                 codec ("zlib" | "none"), bits_bytes (stored length of the bit block),
                 payload_bytes, crc32 (of the whole payload)
    12+L         payload: area int64[N] | score float32[N] (if has_score) | bit block

The bit block is ``np.packbits(masks.reshape(-1))`` (row-major [N, H, W], most significant bit
first, the same bit order as the paper's big-endian bitarray), zlib-compressed by default:
SAM-like masks are large smooth regions and compress ~10-50x beyond plain bit packing.

The paper's format (``<scene>/masks/<stem>.pt``) is ``torch.save({'masks': bitarray(N*H*W),
'N': N, 'H': H, 'W': W})``; its ``--save_to_tensor`` variant is a plain bool tensor
[N, H, W]. Both are read with ``torch.load(weights_only=True)`` with only ``bitarray`` allowed
beyond torch's own safe types, so a hostile file cannot run code. ``masks.load`` tells the
formats apart by their first bytes, never by the file name.

Every problem with a file raises ``MaskFileError`` (``user_facing``) whose one-line message
names the file and what is wrong.
"""

from __future__ import annotations

import io
import json
import os
import struct
import tempfile
import zlib
from pathlib import Path

import numpy as np

from masks.maskset import MaskError, MaskSet

MAGIC = b"\x89TRMASK\n"
FORMAT_VERSION = 1
SUFFIX = ".masks"
_TORCH_ZIP_MAGIC = b"PK\x03\x04"
_PICKLE_PROTO = b"\x80"  # legacy (pre-1.6) torch.save files start with a pickle opcode
_HEADER_LIMIT = 64 << 20


class MaskFileError(MaskError):
    """A mask file that cannot be read: names the file and the problem on one line."""

    user_facing = True

    def __init__(self, path: os.PathLike | str, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


# ----------------------------------------------------------------------------- helpers
def mask_path(out_dir: os.PathLike | str, view_name: str) -> Path:
    """Where the masks of one view live: ``out_dir/<view name, '/' -> '__'>.masks``."""
    safe = view_name.replace("/", "__").replace("\\", "__")
    return Path(out_dir) / f"{safe}{SUFFIX}"


def atomic_write(path: os.PathLike | str, data: bytes) -> None:
    """Write to a temp file in the same folder, fsync, then rename over ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _pack(masks: np.ndarray) -> bytes:
    """[N, H, W] bool -> packed bits, row-major, MSB first."""
    return np.packbits(masks.reshape(-1), bitorder="big").tobytes()


def _unpack(bits: bytes, n: int, h: int, w: int, bitorder: str = "big") -> np.ndarray:
    flat = np.unpackbits(np.frombuffer(bits, np.uint8), count=n * h * w, bitorder=bitorder)
    return flat.view(bool).reshape(n, h, w)


# ------------------------------------------------------------------------- our format
def to_bytes(ms: MaskSet, codec: str = "zlib", level: int = 6) -> bytes:
    """Serialise ``ms`` in our format."""
    if codec not in ("zlib", "none"):
        raise MaskError(f"unknown codec {codec!r}; use 'zlib' or 'none'")
    bits = _pack(ms.masks)
    if codec == "zlib":
        bits = zlib.compress(bits, level)
    parts = [ms.area.astype("<i8").tobytes()]
    if ms.score is not None:
        parts.append(ms.score.astype("<f4").tobytes())
    parts.append(bits)
    payload = b"".join(parts)
    try:
        info_json = json.loads(json.dumps(ms.info))
    except (TypeError, ValueError) as exc:
        raise MaskError(f"MaskSet.info is not JSON-serialisable: {exc}") from None
    header = {
        "format_version": FORMAT_VERSION,
        "n": ms.n,
        "height": ms.height,
        "width": ms.width,
        "generator": ms.generator,
        "info": info_json,
        "has_score": ms.score is not None,
        "codec": codec,
        "bitorder": "big",
        "bits_bytes": len(bits),
        "payload_bytes": len(payload),
        "crc32": zlib.crc32(payload),
    }
    hb = json.dumps(header, sort_keys=True).encode()
    return MAGIC + struct.pack("<I", len(hb)) + hb + payload


def _parse_header(data: bytes, path) -> tuple[dict, int]:
    if len(data) < len(MAGIC) + 4:
        raise MaskFileError(path, f"truncated: {len(data)} bytes, too short for the header")
    (hl,) = struct.unpack_from("<I", data, len(MAGIC))
    start = len(MAGIC) + 4
    if hl > _HEADER_LIMIT:
        raise MaskFileError(path, f"corrupt header length {hl}")
    if len(data) < start + hl:
        raise MaskFileError(path, f"truncated: header needs {start + hl} bytes, file has {len(data)}")
    try:
        header = json.loads(data[start : start + hl].decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MaskFileError(path, f"corrupt header ({exc.__class__.__name__})") from None
    if not isinstance(header, dict):
        raise MaskFileError(path, "corrupt header (not a JSON object)")
    required = ("format_version", "n", "height", "width", "generator", "has_score", "codec",
                "bits_bytes", "payload_bytes", "crc32")
    missing = [k for k in required if k not in header]
    if missing:
        raise MaskFileError(path, f"header is missing key(s) {', '.join(missing)}")
    if header["format_version"] != FORMAT_VERSION:
        raise MaskFileError(path, f"unsupported format_version {header['format_version']}")
    for k in ("n", "height", "width", "bits_bytes", "payload_bytes"):
        if not isinstance(header[k], int) or header[k] < 0:
            raise MaskFileError(path, f"header key {k!r} must be a non-negative integer")
    return header, start + hl


def from_bytes(data: bytes, path: os.PathLike | str = "<bytes>") -> MaskSet:
    """Parse our format (``path`` only names the source in errors)."""
    if not data.startswith(MAGIC):
        raise MaskFileError(path, "not a trase-bench mask file (wrong magic bytes)")
    header, off = _parse_header(data, path)
    n, h, w = header["n"], header["height"], header["width"]
    payload = data[off:]
    if len(payload) < header["payload_bytes"]:
        raise MaskFileError(
            path, f"truncated: payload has {len(payload)} of {header['payload_bytes']} bytes")
    if len(payload) > header["payload_bytes"]:
        raise MaskFileError(
            path, f"{len(payload) - header['payload_bytes']} unexpected trailing bytes")
    if zlib.crc32(payload) != header["crc32"]:
        raise MaskFileError(path, "checksum mismatch (file is corrupt)")
    n_score = n if header["has_score"] else 0
    expect = 8 * n + 4 * n_score + header["bits_bytes"]
    if expect != len(payload):
        raise MaskFileError(path, f"payload is {len(payload)} bytes, header implies {expect}")
    area = np.frombuffer(payload, "<i8", count=n, offset=0).astype(np.int64)
    score = None
    if header["has_score"]:
        score = np.frombuffer(payload, "<f4", count=n, offset=8 * n).astype(np.float32)
    bits = payload[8 * n + 4 * n_score :]
    if header["codec"] == "zlib":
        try:
            bits = zlib.decompress(bits)
        except zlib.error as exc:
            raise MaskFileError(path, f"corrupt bit block ({exc})") from None
    elif header["codec"] != "none":
        raise MaskFileError(path, f"unknown codec {header['codec']!r}")
    need = (n * h * w + 7) // 8
    if len(bits) != need:
        raise MaskFileError(
            path, f"wrong bit count: {len(bits) * 8} bits stored, N*H*W = {n}*{h}*{w} needs {need * 8}")
    masks = _unpack(bits, n, h, w)
    ms = MaskSet(masks, area, score, str(header["generator"]), dict(header.get("info") or {}))
    real_area = masks.reshape(n, h * w).sum(axis=1, dtype=np.int64)
    if not np.array_equal(real_area, area):
        raise MaskFileError(path, "stored areas do not match the masks (file is corrupt)")
    return ms


def read_header(path: os.PathLike | str) -> dict:
    """The JSON header of one of our files, without decoding the masks."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(len(MAGIC) + 4)
            if not head.startswith(MAGIC):
                raise MaskFileError(path, "not a trase-bench mask file (wrong magic bytes)")
            (hl,) = struct.unpack_from("<I", head, len(MAGIC)) if len(head) == 12 else (0,)
            data = head + f.read(min(hl, _HEADER_LIMIT))
    except OSError as exc:
        raise MaskFileError(path, f"unreadable ({exc.strerror or exc})") from None
    return _parse_header(data, path)[0]


def save(path: os.PathLike | str, ms: MaskSet, codec: str = "zlib") -> Path:
    """Write ``ms`` in our format, atomically. Returns the path."""
    atomic_write(path, to_bytes(ms, codec=codec))
    return Path(path)


# ---------------------------------------------------------------------- paper's format
def _torch_safe_globals() -> list:
    from bitarray import bitarray
    from bitarray._bitarray import _bitarray_reconstructor

    # bytes: an empty bitarray pickles its buffer as bytes() rather than via _codecs.encode
    return [bitarray, _bitarray_reconstructor, bytes]


def official_to_bytes(ms: MaskSet) -> bytes:
    """The paper's ``torch.save({'masks': bitarray, 'N', 'H', 'W'})`` as bytes."""
    import torch
    from bitarray import bitarray

    ba = bitarray(endian="big")
    ba.frombytes(_pack(ms.masks))
    del ba[ms.n * ms.height * ms.width :]  # drop the byte padding: exactly N*H*W bits
    buf = io.BytesIO()
    torch.save({"masks": ba, "N": ms.n, "H": ms.height, "W": ms.width}, buf)
    return buf.getvalue()


def save_official(path: os.PathLike | str, ms: MaskSet) -> Path:
    """Write the paper's format, atomically (scores and generator info are not kept)."""
    atomic_write(path, official_to_bytes(ms))
    return Path(path)


def first_line(exc: BaseException) -> str:
    text = [t.strip() for t in str(exc).strip().splitlines() if t.strip()]
    reason = [t for t in text if t.startswith("WeightsUnpickler error:")]  # torch's real cause
    text = reason or text
    return f"{type(exc).__name__}: {text[0][:160]}" if text else type(exc).__name__


def _from_official(data: bytes, path) -> MaskSet:
    import pickle

    import torch
    from bitarray import bitarray

    try:
        with torch.serialization.safe_globals(_torch_safe_globals()):
            obj = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        raise MaskFileError(path, f"unreadable or unsafe torch file ({first_line(exc)})") from None
    except Exception as exc:  # noqa: BLE001 - torch raises RuntimeError/EOFError/... for damaged archives
        raise MaskFileError(path, f"unreadable torch file, truncated or damaged ({first_line(exc)})") from None
    info = {"source_format": "official"}
    if isinstance(obj, torch.Tensor):  # the paper's --save_to_tensor variant
        if obj.ndim != 3:
            raise MaskFileError(path, f"tensor of shape {tuple(obj.shape)}, expected [N, H, W]")
        return MaskSet.from_masks(obj.numpy().astype(bool), generator="official",
                                  info={"source_format": "official-tensor"})
    if not isinstance(obj, dict):
        raise MaskFileError(path, f"holds a {type(obj).__name__}, expected a dict with masks, N, H, W")
    missing = [k for k in ("masks", "N", "H", "W") if k not in obj]
    if missing:
        raise MaskFileError(path, f"missing key(s) {', '.join(repr(k) for k in missing)}")
    n, h, w = obj["N"], obj["H"], obj["W"]
    for k, v in (("N", n), ("H", h), ("W", w)):
        if isinstance(v, torch.Tensor) and v.numel() == 1:
            v = int(v)
        if not isinstance(v, int) or isinstance(v, bool) or v < 0:
            raise MaskFileError(path, f"key {k!r} must be a non-negative integer, got {v!r}")
    n, h, w = int(n), int(h), int(w)
    ba = obj["masks"]
    if isinstance(ba, bitarray):
        if len(ba) != n * h * w:
            raise MaskFileError(
                path, f"wrong bit count: bitarray holds {len(ba)} bits, N*H*W = {n}*{h}*{w} = {n * h * w}")
        endian = ba.endian() if callable(ba.endian) else ba.endian  # method before bitarray 3
        masks = _unpack(ba.tobytes(), n, h, w, bitorder=endian)
    elif isinstance(ba, torch.Tensor):
        if ba.numel() != n * h * w:
            raise MaskFileError(
                path, f"wrong element count: tensor holds {ba.numel()}, N*H*W = {n * h * w}")
        masks = ba.reshape(n, h, w).numpy().astype(bool)
    else:
        raise MaskFileError(path, f"'masks' is a {type(ba).__name__}, expected a bitarray")
    return MaskSet.from_masks(masks, generator="official", info=info)


# ------------------------------------------------------------------------- dispatcher
def loads(data: bytes, path: os.PathLike | str = "<bytes>") -> MaskSet:
    """Parse either format, chosen by the first bytes."""
    if not data:
        raise MaskFileError(path, "empty file")
    if data.startswith(MAGIC):
        return from_bytes(data, path)
    if MAGIC.startswith(data):
        raise MaskFileError(path, f"truncated: {len(data)} bytes, cut inside the magic bytes")
    if data.startswith((_TORCH_ZIP_MAGIC, _PICKLE_PROTO)):
        return _from_official(data, path)
    raise MaskFileError(path, f"not a mask file (unknown leading bytes {data[:8]!r})")


def load(path: os.PathLike | str) -> MaskSet:
    """Read a mask file in our format or the paper's; told apart by content."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise MaskFileError(path, f"unreadable ({exc.strerror or exc})") from None
    return loads(data, path)
