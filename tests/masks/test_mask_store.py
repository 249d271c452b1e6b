import io
import json
import zipfile
import zlib

import numpy as np
import pytest
import torch
from bitarray import bitarray
from mask_testutils import blob_maskset

import masks
from masks import MaskFileError, MaskSet
from masks.store import MAGIC, official_to_bytes, to_bytes


def paper_style_file(path, m: np.ndarray) -> None:
    """Write a file the way the paper's extract_masks.py does (bitarray from a bool list)."""
    n, h, w = m.shape
    torch.save({"masks": bitarray(m.reshape(-1).tolist()), "N": n, "H": h, "W": w}, path)


def _pickled_record(path) -> bytes:
    with zipfile.ZipFile(path) as z:
        (name,) = [n for n in z.namelist() if n.endswith("/data.pkl")]
        return z.read(name)


def test_official_to_ours_to_official_is_bit_exact(tmp_path):
    ms = blob_maskset()
    src = tmp_path / "00001.pt"
    paper_style_file(src, ms.masks)
    a = masks.load(src)
    assert a.generator == "official" and a.score is None
    assert np.array_equal(a.masks, ms.masks) and np.array_equal(a.area, ms.area)
    ours = masks.save(tmp_path / "x.masks", a)
    assert ours.read_bytes().startswith(MAGIC)
    b = masks.load(ours)
    assert b.equals(a)
    back = masks.save_official(tmp_path / "back.pt", b)
    # same torch + bitarray: the pickled record is byte-identical (the zip's folder name
    # differs: torch names it after the file when given a path)
    assert _pickled_record(back) == _pickled_record(src)
    assert masks.load(back).equals(a)


def test_ours_round_trip_keeps_score_generator_info(tmp_path):
    ms = blob_maskset(seed=3)
    for codec in ("zlib", "none"):
        p = masks.save(tmp_path / f"a_{codec}.masks", ms, codec=codec)
        r = masks.load(p)
        assert r.equals(ms) and r.generator == "test" and r.info == {"seed": 3}
    assert masks.read_header(p)["n"] == ms.n


def test_format_is_told_by_content_not_extension(tmp_path):
    ms = blob_maskset(seed=1)
    p1 = tmp_path / "ours_named.pt"
    p1.write_bytes(to_bytes(ms))
    p2 = tmp_path / "paper_named.masks"
    p2.write_bytes(official_to_bytes(ms))
    assert masks.load(p1).equals(ms) and masks.load(p2).equals(ms, check_score=False)


def test_rle_round_trip(tmp_path):
    ms = blob_maskset(seed=2)
    r = masks.from_rle(masks.to_rle(ms), ms.height, ms.width, ms.score, ms.generator, ms.info)
    assert r.equals(ms)
    p = masks.save_coco_json(tmp_path / "m.json", ms)
    r2 = masks.load_coco_json(p)
    assert r2.equals(ms) and r2.generator == "test"
    back = masks.load(masks.save(tmp_path / "m.masks", r2))
    assert back.equals(ms)


def test_empty_and_tiny_sets(tmp_path):
    e = MaskSet.empty(5, 7, generator="g")
    assert masks.load(masks.save(tmp_path / "e.masks", e)).equals(e)
    assert masks.load(masks.save_official(tmp_path / "e.pt", e)).n == 0
    assert masks.from_rle(masks.to_rle(e), 5, 7).n == 0
    one = MaskSet.from_masks(np.ones((1, 1, 1), bool))
    assert masks.load(masks.save_official(tmp_path / "o.pt", one)).equals(one, check_score=False)


def test_paper_tensor_variant(tmp_path):
    ms = blob_maskset()
    p = tmp_path / "t.pt"
    torch.save(torch.from_numpy(ms.masks), p)
    assert masks.load(p).equals(ms, check_score=False)


def test_pixel_mean_area():
    m = np.zeros((3, 2, 3), bool)
    m[0, 0, :] = True  # area 3
    m[1, :, 0] = True  # area 2
    m[2] = True  # area 6
    ms = MaskSet.from_masks(m)
    exp = np.array([[(3 + 2 + 6) / 3, (3 + 6) / 2, (3 + 6) / 2], [(2 + 6) / 2, 6, 6]], np.float32)
    assert np.allclose(ms.pixel_mean_area, exp)
    assert ms.pixel_mean_area.dtype == np.float32
    assert np.array_equal(MaskSet.from_masks(m[:2]).pixel_mean_area[1, 1:], [0, 0])


# ---------------------------------------------------------------- corrupt files
def _err(path) -> str:
    with pytest.raises(MaskFileError) as ei:
        masks.load(path)
    msg = str(ei.value)
    assert str(path) in msg and "\n" not in msg
    assert getattr(ei.value, "user_facing", False)
    return msg


def test_corrupt_official_files(tmp_path):
    ms = blob_maskset()
    n, h, w = ms.masks.shape
    p = tmp_path / "bits.pt"
    torch.save({"masks": bitarray(ms.masks.reshape(-1).tolist()[:-3]), "N": n, "H": h, "W": w}, p)
    assert "wrong bit count" in _err(p)
    p = tmp_path / "key.pt"
    torch.save({"masks": bitarray(ms.masks.reshape(-1).tolist()), "N": n, "H": h}, p)
    assert "missing key" in _err(p) and "'W'" in _err(p)
    p = tmp_path / "trunc.pt"
    p.write_bytes(official_to_bytes(ms)[:200])
    assert "unreadable" in _err(p)
    p = tmp_path / "evil.pt"
    torch.save({"masks": io.StringIO("x"), "N": 1, "H": 1, "W": 1}, p)  # non-allow-listed global
    assert "unsafe" in _err(p) or "unreadable" in _err(p)
    p = tmp_path / "neg.pt"
    torch.save({"masks": bitarray(), "N": -1, "H": 1, "W": 1}, p)
    assert "non-negative" in _err(p)


def test_corrupt_own_files(tmp_path):
    ms = blob_maskset()
    good = to_bytes(ms)
    cases = {
        "trunc": good[:-5],
        "tiny": good[:6],
        "flip": good[:-4] + bytes([good[-4] ^ 0xFF]) + good[-3:],
        "junk": b"hello world",
        "empty": b"",
        "trail": good + b"\0",
    }
    expect = {"trunc": "truncated", "tiny": "truncated", "flip": "checksum", "junk": "not a mask",
              "empty": "empty", "trail": "trailing"}
    for name, data in cases.items():
        p = tmp_path / f"{name}.masks"
        p.write_bytes(data)
        assert expect[name] in _err(p), name
    assert "unreadable" in _err(tmp_path / "missing.masks")


def test_wrong_bit_count_in_own_file(tmp_path):
    """A consistent file (valid checksum) whose bit block is too short for N*H*W."""
    ms = blob_maskset()
    data = to_bytes(ms, codec="none")
    hl = int.from_bytes(data[8:12], "little")
    header = json.loads(data[12 : 12 + hl])
    payload = data[12 + hl : -1]  # one byte of bits short
    header.update(bits_bytes=header["bits_bytes"] - 1, payload_bytes=len(payload),
                  crc32=zlib.crc32(payload))
    hb = json.dumps(header).encode()
    p = tmp_path / "bits.masks"
    p.write_bytes(MAGIC + len(hb).to_bytes(4, "little") + hb + payload)
    assert "wrong bit count" in _err(p)


def test_compression_report():
    ms = blob_maskset(n=20, h=60, w=80)
    r = masks.compression_report(ms)
    assert r.dense_bool == 20 * 60 * 80 and r.packed_bits == r.dense_bool // 8
    assert r.ours < r.ours_uncompressed and r.ours < r.official
    table = masks.format_compression_table([r])
    assert "official" in table and "ours" in table


def test_mask_path():
    assert masks.mask_path("/o", "cam03/00012").name == "cam03__00012.masks"
