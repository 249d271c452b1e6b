from pathlib import Path

import pytest

from trase.io import atomic_directory, atomic_path, atomic_write_text


def test_stale_temporaries_of_a_killed_writer_are_swept(tmp_path):
    # what a SIGKILL during atomic writes of pred/ and results.json leaves behind
    (tmp_path / ".pred.abc.tmp").mkdir()
    (tmp_path / ".pred.abc.tmp" / "00000.png").write_bytes(b"half")
    (tmp_path / ".results.json.x.tmp").write_text("{")
    with atomic_directory(tmp_path / "pred") as d:
        (d / "00000.png").write_bytes(b"whole")
    atomic_write_text(tmp_path / "results.json", "{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pred", "results.json"]
    assert (tmp_path / "pred" / "00000.png").read_bytes() == b"whole"


def test_failed_write_leaves_old_file(tmp_path):
    p = tmp_path / "f.txt"
    atomic_write_text(p, "old")
    with pytest.raises(RuntimeError), atomic_path(p) as tmp:
        Path(tmp).write_text("half")
        raise RuntimeError
    assert p.read_text() == "old" and [x.name for x in tmp_path.iterdir()] == ["f.txt"]
