"""The example package's method (examples/trase-bench-example-method), in this process: its
presets, and fit/segment on a tiny scene, through the registry as its entry point names it.
The slow test beside it installs the package into a fresh environment and runs it end to end."""

import dataclasses
from pathlib import Path

import pytest

import masks as masklib
from benchmark.methods import FittedModel, check_method_class, get_method
from benchmark.protocol.prompts import make_benchmark_prompts
from benchmark.scoring import score_masks
from tests.benchmark.methods.plugin_fakes import fake_plugins
from tests.trase.helpers import exact_masks, tiny_scene

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "trase-bench-example-method"


def _entry_point() -> tuple[str, str]:
    """(name, value) of the method's entry point, as the example's pyproject.toml declares it."""
    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib

    table = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())["project"]["entry-points"]["trase_bench.methods"]
    ((name, value),) = table.items()
    return name, value


@pytest.fixture
def example(monkeypatch, tmp_path):
    """The example's method registered as its package's entry point declares it."""
    monkeypatch.syspath_prepend(str(EXAMPLE / "src"))
    install = fake_plugins(monkeypatch, tmp_path)
    name, value = _entry_point()
    next(install)({"trase_bench.methods": {name: value}}, package="trase-bench-example-method", version="0.1.0")
    yield get_method(name)
    next(install, None)


@dataclasses.dataclass
class _Scene:
    train: list
    test: list
    root: Path = Path("tiny")


def test_the_entry_point_names_a_method_with_presets(example):
    assert example.name == "colour-kmeans" and check_method_class(type(example)) is None
    mono, multi = example.settings("paper", "hypernerf"), example.settings("paper", "neu3d")
    assert (mono.clustering.n_clusters, multi.clustering.n_clusters) == (16, 32)
    assert example.settings("cpu", "hypernerf").render_rule == "visible"
    assert example.settings("cpu", "neu3d").render_rule == "alone"
    assert example.settings("cpu", "hypernerf").preset == "cpu"


def test_fit_and_segment_a_tiny_scene(example, tmp_path):
    gm, deform, ids, views = tiny_scene()  # two blobs apart in space, random colours
    masks_dir = tmp_path / "masks"
    for v in views:
        masklib.save(masklib.mask_path(masks_dir, v.name), exact_masks(gm, deform, ids, v))
    scene = _Scene(train=views, test=views)
    cfg = example.settings("paper", "hypernerf")
    cfg.features.position_weight, cfg.clustering.n_clusters = 4.0, 2  # the blobs differ by position only
    fitted = example.fit(scene, gm, deform, masks_dir, cfg, tmp_path / "fit", progress=False)
    assert fitted.features.shape == (len(ids), 6) and fitted.stats["n_clusters"] == 2
    assert set(fitted.labels[ids == 0]) != set(fitted.labels[ids == 1])  # one cluster per blob
    gts = [exact_masks(gm, deform, ids, v).masks[0] for v in views]
    prompts = make_benchmark_prompts(views, gts)
    preds = example.segment(fitted, scene, prompts)
    names = [str(i) for i in range(len(views))]
    assert score_masks(dict(zip(names, preds)), dict(zip(names, gts))).miou > 0.8
    assert len(fitted.stats["click_clusters"]) == len(prompts.clicks)
    opreds, oclusters = example.segment_oracle(fitted, scene, gts)
    assert len(opreds) == len(views) and len(oclusters) == 1
    # the benchmark saves the fitted model and reads it back typed as the method's settings
    fitted.save(tmp_path / "out")
    back = FittedModel.load(tmp_path / "out", gm, deform, example.settings_class())
    assert back.config == cfg and (back.labels == fitted.labels).all()
