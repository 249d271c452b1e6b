"""The example method package (examples/trase-bench-example-method), installed into a fresh
virtual environment as a user would install a method of their own, appears in
``trase-bench methods`` and makes a leaderboard row through ``trase-bench run``.

The environment sees this interpreter's installed packages (torch, numpy ...) through a .pth
line, so nothing is downloaded: pip installs this project (editable) and the example package
(from a copy), neither with dependencies nor an index."""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "examples" / "trase-bench-example-method"


def _fresh_env(where: Path) -> Path:
    """A virtual environment that sees this interpreter's site-packages; -> its bin folder."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(where)], check=True)
    bin_dir = where / ("Scripts" if os.name == "nt" else "bin")
    python = bin_dir / "python"
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    ours = [p for p in sys.path if p.endswith(("site-packages", "dist-packages")) and Path(p).is_dir()]
    # addsitedir, not a plain path line: the outer folders' own .pth files (editable installs,
    # such as the competitors' packages) are processed too
    (Path(site) / "_outer_site_packages.pth").write_text(
        "".join(f"import site; site.addsitedir({p!r})\n" for p in ours))
    return bin_dir


def _run(args: list, env: dict, cwd: Path) -> subprocess.CompletedProcess:
    done = subprocess.run([str(a) for a in args], env=env, cwd=cwd, capture_output=True, text=True, timeout=300,
                          check=False)
    assert done.returncode == 0, f"{args}: exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    return done


@pytest.mark.slow
def test_example_package_installs_lists_runs_and_ranks(tmp_path):
    t0 = time.perf_counter()
    bin_dir = _fresh_env(tmp_path / "venv")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env |= {"TRASE_BENCH_CACHE": str(tmp_path / "cache"), "TRASE_PRECOMPILE": "0", "PIP_DISABLE_PIP_VERSION_CHECK": "1",
            "PIP_NO_INPUT": "1", "PATH": f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"}
    example = shutil.copytree(EXAMPLE, tmp_path / "example")  # pip builds in the source folder: a copy
    _run([bin_dir / "python", "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", "--no-index",
          "-e", ROOT, example], env, tmp_path)
    # the environment runs this checkout and the installed example, nothing else of them
    code = "import benchmark, trase_bench_example_method as m; print(benchmark.__file__); print(m.__file__)"
    where = _run([bin_dir / "python", "-c", code], env, tmp_path).stdout.split()
    assert Path(where[0]).is_relative_to(ROOT) and Path(where[1]).is_relative_to(tmp_path / "venv")

    listed = _run([bin_dir / "trase-bench", "methods"], env, tmp_path)
    rows = {line.split()[0]: line.split(None, 1)[1] for line in listed.stdout.splitlines() if line.startswith("  ")}
    assert rows["colour-kmeans"].startswith("trase-bench-example-method 0.1.0  k-means on the gaussians' colours")
    assert rows["trase"].startswith("built-in") and listed.stderr == ""  # no plugin warning
    data = json.loads(_run([bin_dir / "trase-bench", "methods", "--json"], env, tmp_path).stdout)
    assert data["methods"]["colour-kmeans"]["entry_point"] == \
        "colour-kmeans = trase_bench_example_method.method:ColourKMeans"

    runs = tmp_path / "runs"
    _run([bin_dir / "trase-bench", "run", "--method", "colour-kmeans", "--dataset", "hypernerf",
          "--sequence", "synthetic-tiny", "--runs", runs, "--set", "geometry.source=ground-truth", "--quiet"],
         env, tmp_path)
    (path,) = runs.glob("colour-kmeans/hypernerf/synthetic-tiny/*/results.json")
    record = json.loads(path.read_text())
    assert record["method"] == "colour-kmeans" and record["versions"]["trase-bench-example-method"] == "0.1.0"
    assert record["config"]["method"]["clustering"]["n_clusters"] == 16  # the plugin's own presets
    assert record["stages"]["features"]["key"] and (path.parent / "pred" / "00000.png").is_file()
    miou = record["metrics"]["official"]["miou"]
    assert 0.0 <= miou <= 1.0

    board = _run([bin_dir / "trase-bench", "leaderboard", "--runs", runs, "--kind", "run"], env, tmp_path).stdout
    row = next(line for line in board.splitlines() if line.startswith("| colour-kmeans"))
    assert f"{miou:.4f}" in row
    print(f"example package: installed, listed, run and ranked in {time.perf_counter() - t0:.1f} s; row: {row}")
