"""The toolkit's one cache folder: one variable names it; the earlier one is read with a notice."""

from pathlib import Path

import cachedir


def test_the_variable_names_the_folder_and_wins_over_the_earlier_name(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path / "new"))
    monkeypatch.setenv("TRASE_CACHE", str(tmp_path / "old"))
    assert cachedir.root() == tmp_path / "new" and cachedir.subfolder("weights") == tmp_path / "new" / "weights"
    assert capsys.readouterr().err == ""


def test_the_earlier_name_is_read_with_a_notice(monkeypatch, tmp_path, capsys):
    monkeypatch.delenv("TRASE_BENCH_CACHE", raising=False)
    monkeypatch.setenv("TRASE_CACHE", str(tmp_path / "old"))
    monkeypatch.setattr(cachedir, "_noticed", [])
    assert cachedir.subfolder("synthetic") == tmp_path / "old" / "synthetic"
    assert "set $TRASE_BENCH_CACHE instead" in capsys.readouterr().err


def test_the_default_is_the_users_cache(monkeypatch, tmp_path):
    monkeypatch.delenv("TRASE_BENCH_CACHE", raising=False)
    monkeypatch.delenv("TRASE_CACHE", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    assert cachedir.root() == Path(tmp_path) / ".cache" / "trase-bench"
