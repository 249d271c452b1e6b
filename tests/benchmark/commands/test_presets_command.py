"""``trase-bench presets``: the list, and one preset resolved setting by setting with where
each value was declared."""

import json

from click.testing import CliRunner

from benchmark.commands.presets import presets


def _run(*args):
    result = CliRunner().invoke(presets, list(args))
    assert result.exit_code == 0, result.output
    return result.output


def test_lists_the_presets_with_their_bases():
    out = _run()
    assert "cpu-v3 cpu-v2 over twice the iterations on a monocular capture [from cpu-v2]" in " ".join(out.split())
    assert out.splitlines()[1].split()[0] == "paper"


def test_one_preset_resolved_names_each_values_declaration():
    rows = json.loads(_run("--preset", "cpu", "--dataset", "neu3d", "--image-size", "1352x1014", "--json",
                           "--set", "method.features.lr=0.05"))
    assert rows["geometry.train.iterations"]["value"] == 4000
    assert rows["geometry.train.iterations"]["declared"].startswith("trase/reconstruction_presets.py:")
    assert rows["geometry.train.iterations"]["declared"].endswith("(multi-view)")
    assert rows["geometry.train.image_downscale"]["value"] == 4.0
    assert rows["method.features.lr"] == {"value": 0.05, "declared": "--set"}
    assert rows["method.filter_threshold"]["declared"].startswith("benchmark/methods/trase_presets.py:")
    assert rows["method.clustering.params.min_cluster_size"]["value"] == 50
    assert rows["geometry.train.lambda_dssim"]["declared"] == "default (ReconstructionConfig)"
    paper = json.loads(_run("--preset", "paper", "--dataset", "hypernerf", "--json"))
    assert paper["geometry.train.warm_up"]["value"] == 1500 and "(a benchmark)" in paper["geometry.train.warm_up"]["declared"]
    assert paper["method.filter_threshold"]["declared"].endswith("(dataset hypernerf)")


def test_the_table_hides_defaults_unless_asked_and_a_capture_takes_its_rig():
    short, full = _run("--preset", "cpu", "--rig", "multi-view"), _run("--preset", "cpu", "--rig", "multi-view", "--all")
    assert "default (FeatureConfig)" not in short and "default (FeatureConfig)" in full
    assert "more settings keep their config class's default" in short
    assert "masks.dir" in full  # a capture: masks from files are possible
    rows = {line.split()[0]: line.split()[1] for line in short.splitlines() if line.startswith("method.features.n_")}
    assert rows == {"method.features.n_pixels": "2000", "method.features.n_masks": "50.0"}  # the multi-view rig's M'
    bad = CliRunner().invoke(presets, ["--preset", "cpu", "--image-size", "big"])
    assert bad.exit_code != 0 and "give WxH" in bad.output
