"""Run config: ``--set`` parsing, merging (a misspelt key is an error) and the one typed check."""

from __future__ import annotations

import pytest

from benchmark.config import ConfigError, merge, parse_overrides, typed
from benchmark.datasets.registry import get_dataset
from benchmark.methods import get_method
from tests.benchmark.settings_helpers import resolved_dict
from trase.features import FeatureConfig
from trase.reconstruction_config import ReconstructionConfig


def test_typed_builds_the_dataclass_and_names_a_wrong_value():
    cfg = typed(ReconstructionConfig, {"iterations": 10, "image_downscale": 2, "white_background": True}, "geometry.train")
    assert cfg.iterations == 10 and cfg.image_downscale == 2 and cfg.white_background is True
    with pytest.raises(ConfigError, match=r'--set geometry.train.iterations="many": expected a whole number'):
        typed(ReconstructionConfig, {"iterations": "many"}, "geometry.train")
    with pytest.raises(ConfigError, match="expected a whole number"):
        typed(ReconstructionConfig, {"iterations": True}, "geometry.train")  # a bool is not a count
    with pytest.raises(ConfigError, match="expected true or false"):
        typed(ReconstructionConfig, {"white_background": 1}, "geometry.train")
    with pytest.raises(ConfigError, match="--set geometry.train.nope: unknown setting"):
        typed(ReconstructionConfig, {"nope": 1}, "geometry.train")
    with pytest.raises(ConfigError, match="geometry.train: densify_statistic must be one of"):
        typed(ReconstructionConfig, {"densify_statistic": "mean"}, "geometry.train")  # the class's own check
    # unions: fastpath is a bool or a string
    assert typed(FeatureConfig, {"fastpath": "auto"}, "f").fastpath == "auto"
    assert typed(FeatureConfig, {"fastpath": False}, "f").fastpath is False
    with pytest.raises(ConfigError, match="expected true or false or a string"):
        typed(FeatureConfig, {"fastpath": 3}, "method.features")


def test_the_run_config_is_checked_once_before_any_stage():
    method, spec = get_method("trase"), get_dataset("hypernerf")
    ok = resolved_dict(method, spec, "synthetic", parse_overrides(["method.features.iterations=5"]))
    assert ok["method"]["features"]["iterations"] == 5
    for bad, message in (("geometry.train.iterations=ten", "geometry.train.iterations"),
                         ("method.features.dim=8.5", "method.features.dim"),
                         ("method.features.objective_params=3", "method.features.objective_params")):
        with pytest.raises(ConfigError, match=message):
            resolved_dict(method, spec, "synthetic", parse_overrides([bad]))


def test_merge_rejects_a_misspelt_key_and_opens_params_sections():
    base = {"a": {"b": 1, "params": {}}}
    assert merge(base, {"a": {"params": {"free": 2}}}) == {"a": {"b": 1, "params": {"free": 2}}}
    with pytest.raises(ConfigError, match=r"--set a.c: unknown setting \(known here: b, params\)"):
        merge(base, {"a": {"c": 1}})


def test_devices_are_resolved_once_into_the_config():
    import torch

    spec, method = get_dataset("hypernerf"), get_method("trase")
    cfg = resolved_dict(method, spec, "synthetic", {})
    here = "cuda" if torch.cuda.is_available() else "cpu"
    assert cfg["geometry"]["train"]["device"] == here and cfg["method"]["features"]["device"] == here
    pinned = resolved_dict(method, spec, "synthetic", parse_overrides(["geometry.train.device=cpu",
                                                                        "method.features.device=cpu"]))
    assert pinned["geometry"]["train"]["device"] == "cpu" and pinned["method"]["features"]["device"] == "cpu"
    with pytest.raises(ConfigError, match=r"^--set geometry.train.device: unknown device 'gpu'; choose auto, cpu, cuda$"):
        resolved_dict(method, spec, "synthetic", parse_overrides(["geometry.train.device=gpu"]))
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="method.features.device: device cuda: torch sees no GPU"):
            resolved_dict(method, spec, "synthetic", parse_overrides(["method.features.device=cuda"]))


def test_a_gpu_without_gsplat_stops_the_run_before_any_stage(monkeypatch):
    import importlib.util

    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "gsplat" else real(n, *a))
    spec, method = get_dataset("hypernerf"), get_method("trase")
    with pytest.raises(ConfigError, match=r"^geometry.train.device: device cuda draws with gsplat, which is not "
                                          r"installed \(pip install -e '.\[gpu\]'\); or --set geometry.train.device=cpu$"):
        resolved_dict(method, spec, "synthetic", {})
    cpu = resolved_dict(method, spec, "synthetic", parse_overrides(["geometry.train.device=cpu",
                                                                     "method.features.device=cpu"]))
    assert cpu["geometry"]["preset"] == "paper"  # auto preset: paper where torch sees a GPU
