"""A command method's TOML file (benchmark.methods.command): what it declares, one-line errors
naming the file, and how a run resolves it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from benchmark.methods import get_method
from benchmark.methods.command import (
    DEFAULT_TIMEOUT_S,
    CommandError,
    CommandMethod,
    CommandSettings,
    fill,
    read_command_toml,
    uses_placeholder,
)
from lazyspecs.presets import Context

GOOD = """
name = "discs"
description = "a disc around each click"
command = ["venv/bin/python", "predict.py", "{input}", "{output}", "--preset={preset}"]
workdir = "."
timeout = 90
version = "2"
[env]
OMP_NUM_THREADS = "2"
METHOD_HOME = "{method_dir}"
"""


def _toml(tmp_path: Path, body: str, name: str = "method.toml") -> Path:
    p = tmp_path / name
    p.write_text(body)
    return p


def test_a_good_file_declares_the_method(tmp_path):
    path = _toml(tmp_path, GOOD)
    s = read_command_toml(path)
    assert (s.name, s.description, s.version, s.workdir, s.timeout) == ("discs", "a disc around each click", "2", ".", 90.0)
    assert s.command[2:4] == ["{input}", "{output}"] and s.env == {"OMP_NUM_THREADS": "2", "METHOD_HOME": "{method_dir}"}
    assert len(s.toml_sha256) == 64
    assert uses_placeholder(s, "preset") and uses_placeholder(s, "method_dir") and not uses_placeholder(s, "scene")
    assert fill("{input}/x {{literal}}", {"input": "/in"}) == "/in/x {literal}"
    # optional keys: the TOML's folder, the default timeout, no environment
    s = read_command_toml(_toml(tmp_path, 'name = "m"\ncommand = ["true"]', "minimal.toml"))
    assert (s.workdir, s.timeout, s.env, s.version) == (".", DEFAULT_TIMEOUT_S, {}, "")


def test_a_changed_file_is_another_method_version(tmp_path):
    a = read_command_toml(_toml(tmp_path, GOOD))
    b = read_command_toml(_toml(tmp_path, GOOD.replace('version = "2"', 'version = "3"'), "b.toml"))
    assert a.toml_sha256 != b.toml_sha256


@pytest.mark.parametrize("body, message", [
    ('name = "m"\ncommand = [', "malformed TOML"),
    ('name = "m"', "command must be a non-empty list"),
    ('name = "m"\ncommand = []', "command must be a non-empty list"),
    ('name = "m"\ncommand = "python predict.py"', "command must be a non-empty list"),
    ('name = "m"\ncommand = ["python", 3]', "command must be a non-empty list"),
    ('name = "m"\ncommand = ["true"]\ntimeout = 0', "timeout must be a number of seconds > 0"),
    ('name = "m"\ncommand = ["true"]\ntimeout = -5', "timeout must be a number of seconds > 0"),
    ('name = "m"\ncommand = ["true"]\ntimeout = "ten"', "timeout must be a number of seconds > 0"),
    ('name = "m"\ncommand = ["true"]\ntimeout = true', "timeout must be a number of seconds > 0"),
    ('name = "m"\ncommand = ["true"]\ntimeout = inf', "timeout must be a number of seconds > 0"),
    ('command = ["true"]', "name must be a string"),
    ('name = "a/b"\ncommand = ["true"]', "name must be a string"),
    ('name = "trase"\ncommand = ["true"]', "'trase' is a registered method"),
    ('name = "m"\ncommand = ["true"]\ncmd = ["x"]', "unknown key 'cmd'"),
    ('name = "m"\ncommand = ["run", "{outptu}"]', "unknown placeholder {outptu}"),
    ('name = "m"\ncommand = ["run", "{output!r}"]', "unknown placeholder {output}"),
    ('name = "m"\ncommand = ["run", "{"]', "literal braces"),
    ('name = "m"\ncommand = ["true"]\n[env]\nN = 2', "[env] must be a table of strings"),
    ('name = "m"\ncommand = ["true"]\n[env]\nN = "{nope}"', "env.N: unknown placeholder {nope}"),
    ('name = "m"\ncommand = ["true"]\nworkdir = "no-such-folder"', "workdir 'no-such-folder' is not a folder"),
    ('name = "m"\ncommand = ["true"]\nversion = 2', "version must be a string"),
])
def test_bad_files_are_one_line_naming_the_file(tmp_path, body, message):
    path = _toml(tmp_path, body)
    with pytest.raises(CommandError) as err:
        read_command_toml(path)
    text = str(err.value)
    assert text.startswith(f"{path}: ") and message in text and "\n" not in text


def test_missing_and_undecodable_files(tmp_path):
    with pytest.raises(CommandError, match="command method file not found"):
        get_method(str(tmp_path / "absent.toml"))
    path = tmp_path / "latin1.toml"
    path.write_bytes(b'name = "caf\xe9"\n')
    with pytest.raises(CommandError, match=r"latin1.toml: not UTF-8 \(byte 11\)"):
        read_command_toml(path)


def test_get_method_reads_a_toml_path(tmp_path):
    path = _toml(tmp_path, GOOD)
    method = get_method(str(path))
    assert isinstance(method, CommandMethod) and method.name == "discs" and method.path == path
    with pytest.raises(CommandError, match="takes no options"):
        get_method(str(path), objective="trase-hard")


def test_settings_follow_the_run_preset_and_are_checked(tmp_path):
    method = get_method(str(_toml(tmp_path, GOOD)))
    resolved = method.resolve_settings("paper", Context(dataset="hypernerf"))
    assert isinstance(resolved.config, CommandSettings) and resolved.config.preset == "paper"
    assert resolved.sources["timeout"] == str(method.path) and resolved.sources["preset"] == "the run's preset"
    resolved.config.env["X"] = "1"  # a run's copy: the method's declaration is left as it was
    assert "X" not in method.declared.env
    method.check_settings(resolved.config)
    from benchmark.config import ConfigError

    with pytest.raises(ConfigError, match="method.timeout=0"):
        method.check_settings(dataclasses.replace(resolved.config, timeout=0))
    with pytest.raises(CommandError, match="a command method segments a benchmark's test views"):
        method.resolve_settings("cpu", Context(dataset=None))  # trase-bench fit on a capture


def test_run_settings_record_the_command(tmp_path):
    from benchmark.datasets.registry import get_dataset
    from benchmark.pipeline.settings import run_settings

    method = get_method(str(_toml(tmp_path, GOOD)))
    spec = get_dataset("hypernerf")
    plain = run_settings(method, spec, "synthetic", {})
    assert plain.is_default and plain.to_dict()["method"]["command"][0] == "venv/bin/python"
    changed = run_settings(method, spec, "synthetic", {"method": {"timeout": 5}})
    assert changed.method.timeout == 5 and not changed.is_default and changed.group_hash != plain.group_hash


def test_the_protocol_says_the_geometry_is_the_methods_own(tmp_path):
    from benchmark.results.runs import protocol

    record = {"config": {"method": {"command": ["x"], "toml_sha256": "ab" * 32, "preset": "cpu"},
                         "geometry": {"source": "reconstruct", "preset": "cpu"}, "masks": {"generator": "synthetic"},
                         "prompts": {"rule": "gt-first-appearance"}},
              "metrics": {"official": {"metric_version": "official/script1"}}}
    p = protocol(record)
    assert p["geometry"] == "the method's own (a command method)" and p["features"].endswith("(TOML sha256 abababababab)")
    assert p["render"] == "the method's own" and p["prompts"] == "gt-first-appearance"
