from benchmark.datasets.registry import DATASETS
from benchmark.methods.trase_settings import OWN_CAPTURE_THRESHOLD, PAPER_SETTINGS, dataset_settings


def test_the_papers_settings_for_each_benchmark():
    assert list(PAPER_SETTINGS) == list(DATASETS)
    s = PAPER_SETTINGS
    assert [s[k].filter_threshold for k in s] == [0.4, 0.9, 0.98, 0.6, 0.9]
    assert [(s[k].n_pixels, s[k].n_masks) for k in s] == [
        (5000, 25), (5000, 25), (10000, 50), (10000, 50), (10000, 50)]
    # Np and M' follow the rig the registry records
    for key, spec in DATASETS.items():
        assert (s[key].n_masks == 25) == spec.monocular


def test_own_capture_takes_its_rigs_settings():
    mono, multi = dataset_settings(None, monocular=True), dataset_settings(None, monocular=False)
    assert (mono.n_pixels, mono.n_masks) == (5000, 25) and (multi.n_pixels, multi.n_masks) == (10000, 50)
    assert mono.filter_threshold == multi.filter_threshold == OWN_CAPTURE_THRESHOLD
    assert dataset_settings("neu3d", monocular=True) == PAPER_SETTINGS["neu3d"]  # a benchmark's own win
