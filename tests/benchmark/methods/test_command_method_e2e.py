"""A method in its own environment, end to end: a virtual environment made here (the standard
library only: it cannot import the toolkit's packages), the example method's script
(examples/command-method/predict.py) run in it through ``trase-bench run --method
method.toml`` on the tiny HyperNeRF-format scene, its row on the leaderboard, a rerun that
reuses its output; and a command that fails, hangs or writes nothing: one line naming its
log, no result left behind."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from benchmark.cli import main
from benchmark.results import load_results
from benchmark.scoring import score_directories

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "command-method"
SEQ = "synthetic-tiny"
# runs the example's predict.py, counting its calls (a rerun must not call it again)
COUNTED = """import runpy, sys
with open("calls.txt", "a") as f:
    f.write("called\\n")
sys.argv = ["predict.py", *sys.argv[1:]]
runpy.run_path("predict.py", run_name="__main__")
"""

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def venv_python(tmp_path_factory) -> Path:
    """A fresh virtual environment's interpreter, without pip or the toolkit's packages."""
    env = tmp_path_factory.mktemp("method-env") / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env)], check=True, timeout=120)
    python = env / "bin" / "python"
    isolated = subprocess.run([str(python), "-c", "import numpy"], check=False, capture_output=True,
                              env={"PATH": "/usr/bin:/bin"})
    assert isolated.returncode != 0  # its own environment: not even numpy
    return python


def _method(folder: Path, name: str, command: list[str], timeout: float = 120) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "method.toml"
    path.write_text(f'name = "{name}"\ncommand = {json.dumps(command)}\ntimeout = {timeout}\n')
    return path


def _run(toml: Path, runs: Path) -> int:
    """The tiny synthetic scene, generated once per machine (~/.cache/trase-bench/synthetic)."""
    return main(["run", "--method", str(toml), "--dataset", "hypernerf", "--sequence", SEQ, "--runs", str(runs),
                 "--quiet"])


def test_a_script_in_its_own_environment_makes_a_leaderboard_row(venv_python, tmp_path, capsys):
    folder = tmp_path / "method"
    folder.mkdir()
    shutil.copy(EXAMPLE / "predict.py", folder / "predict.py")
    (folder / "counted.py").write_text(COUNTED)
    toml = _method(folder, "click-discs", [str(venv_python), "counted.py", "{input}", "{output}", "--radius", "0.12"])
    runs = tmp_path / "runs"
    t0 = time.monotonic()
    assert _run(toml, runs) == 0
    seconds = time.monotonic() - t0
    (path,) = (runs / "click-discs" / "hypernerf" / SEQ).glob("*/results.json")
    r = load_results(path)
    assert r["method"] == "click-discs" and r["run"]["kind"] == "main" and r["variant"] == "synthetic"
    assert list(r["stages"]) == ["masks", "prompts", "command-inputs", "command", "evaluate"]
    cmd = r["stages"]["command"]["info"]
    assert cmd["command"][:2] == [str(venv_python), "counted.py"] and cmd["exit_status"] == 0
    assert cmd["n_masks"] == len(r["frames"]) == 3 and cmd["workdir"] == str(folder.resolve())
    log = Path(cmd["log"]).read_text()
    assert "3 training views (3 with masks), 3 test views" in log and "exit status 0" in log
    assert (path.parent / "command" / "command.log").read_text() == log
    assert r["config"]["method"]["toml_sha256"] and r["n_gaussians"] is None and r["oracle"] is None
    official = r["metrics"]["official"]
    assert 0.1 < official["miou"] < 1 and r["metrics"]["miou"] == official["miou"]
    # the run's masks, scored as files by `trase-bench score`, give the run's numbers
    by_files = score_directories(path.parent / "pred", Path(r["frames"][0]["gt"]).parent, "official")
    assert by_files.miou == official["miou"] and by_files.macc == official["macc"]
    out = capsys.readouterr().out
    assert re.search(rf"click-discs hypernerf/{SEQ} \(synthetic, run c[0-9a-f]{{8}}, main, seed 0\): "
                     rf"mIoU {official['miou']:.4f}", out)

    assert main(["leaderboard", "--runs", str(runs)]) == 0
    board = capsys.readouterr().out
    row = next(line for line in board.splitlines() if line.startswith("| click-discs"))
    assert f"{official['miou']:.4f}" in row and f"{official['macc']:.4f}" in row
    assert "geometry the method's own (a command method)" in board
    print(f"\nleaderboard row: {row}\nfirst run {seconds:.1f} s")  # the figures of the closing note

    # a rerun reuses the command's output: the script is not run again
    assert _run(toml, runs) == 0
    again = load_results(path)
    assert again["stages"]["command"]["skipped"] and again["metrics"] == r["metrics"]
    assert (folder / "calls.txt").read_text() == "called\n"


def _failed(toml: Path, runs: Path, capsys) -> tuple[str, Path]:
    """Run a failing method: (its one error line, its log); nothing of it is left behind."""
    assert _run(toml, runs) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("error: command method ")
    log = Path(re.search(r"\(log: (.+\.failed\.log)\)$", err).group(1))
    assert log.is_file()
    name = toml.parent.name
    assert not (runs / name).exists()  # no run directory, no results.json
    cache = runs / ".cache" / "command"
    assert [p.name for p in cache.iterdir()] == [log.name]  # no stage entry, not even a partial one
    return err, log


@pytest.mark.parametrize("case", ["fails", "hangs", "writes-nothing"])
def test_a_failing_command_leaves_no_result_and_names_its_log(venv_python, tmp_path, capsys, case):
    py = str(venv_python)
    command, timeout = {
        "fails": ([py, "-c", "import sys; print('boom: no CUDA here', file=sys.stderr); sys.exit(3)"], 60),
        "hangs": ([py, "-c", "import time; print('working', flush=True); time.sleep(120)"], 1),
        "writes-nothing": ([py, "-c", "print('done, I think')"], 60),
    }[case]
    toml = _method(tmp_path / case, case, command, timeout)
    t0 = time.monotonic()
    err, log = _failed(toml, tmp_path / "runs", capsys)
    text = log.read_text()
    assert f"command method '{case}' on hypernerf/{SEQ}: " in err
    if case == "fails":
        assert "exit status 3" in err and "boom: no CUDA here" in text
    elif case == "hangs":
        assert "still running after its timeout of 1 s (stopped)" in err and "working" in text
        assert time.monotonic() - t0 < 30
    else:
        assert "its output folder: no masks written (expected one PNG per test frame: 00000.png ... 00002.png)" in err
        assert "done, I think" in text and "# failed: its output folder: no masks written" in text
