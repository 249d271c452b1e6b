"""TRASE's settings as the benchmark runs it: the typed settings and their presets, declared as
data (lazyspecs.presets), each value with the benchmark or rig it applies to and why.

``paper``: the paper's Sec. 4 and its public code's configs (Np and M' by rig, the similarity
filter's threshold per benchmark, HDBSCAN's min_cluster_size 10). ``cpu``: the feature preset
``cpu`` (trase.feature_config) and the constants below, chosen on scenes the benchmark never
reports (docs/notes/cpu-constants.md). A capture of one's own takes its rig's Np / M' and 0.9, the
threshold of two of the five benchmarks (HyperNeRF, Technicolor) and their median.

    TRASE_PRESETS.resolve("cpu", Context(dataset="hypernerf")).config   # a TraseSettings
"""

from __future__ import annotations

import dataclasses

from benchmark.methods import MethodError
from lazyspecs.presets import (
    MONOCULAR,
    MULTIVIEW,
    OWN_CAPTURE,
    Context,
    PresetTable,
    dataset,
    images_below,
    objective,
)
from trase.feature_config import CPU_MAX_PIXELS, FEATURE_PRESETS, FeatureConfig
from trase.prompts import FRONT_SHARE
from trase.reconstruction_presets import CPU_MAX_GAUSSIANS

# The benchmark's click rule under every preset (trase.prompts.CLICK_RULES). "feature" asks
# which cluster the feature rendered under the click belongs to, the query of feature-field
# click prompts (as DGD's and SAGA's), matched to TRASE's clusters instead of thresholded.
# Chosen on selection scenes (seed 1-3, never the benchmark's seed 0; docs/notes/cpu-constants.md,
# "The click rule"): where "weight" chose a wall behind a semi-transparent ring (0.116, oracle
# 0.898) "feature" reached the oracle; every other scene chose the same clusters by both.
CLICK_RULE = "feature"


@dataclasses.dataclass
class ClusteringSettings:
    """HDBSCAN on a sample of the normalised features, then every gaussian assigned."""

    method: str = "hdbscan"
    # HDBSCAN on 2% of the gaussians (public code), but never fewer than 5000: on small scenes
    # 2% is a few hundred points and small objects vanish into noise (synthetic NeRF-DS: mIoU
    # 0.685 with a 500 floor, 0.828 with 5000, same features); at 1M gaussians a 5000-point
    # sample keeps 25%-level agreement (trase-bench perf cluster).
    fraction: float = 0.02
    min_sample: int = 5000
    seed: int = 0
    # the public code's HDBSCAN arguments (min_cluster_size 10, cluster_selection_epsilon 0.01)
    params: dict = dataclasses.field(default_factory=lambda: {"min_cluster_size": 10,
                                                              "cluster_selection_epsilon": 0.01})


@dataclasses.dataclass
class ClickSettings:
    """How a click chooses a cluster (trase.prompts.click_to_cluster)."""

    min_alpha: float = 0.5
    # "feature" = the cluster whose mean feature is nearest the feature rendered under the
    # cursor (3x3 window); "weight" = the cluster rendered most there; "depth" = the paper's
    # depth -> 3D -> nearest gaussian. The benchmark's automatic clicks stand in for the paper's
    # manual ones, which a person corrects on sight; on semi-transparent CPU geometry "depth"
    # chose the background for an object click (synthetic NeRF-DS / Immersive: mIoU 0.10 with
    # oracles 0.56 / 0.77), and "weight" did where an object's gaussians stay semi-transparent
    # (a spinning ring: seed-2 HyperNeRF scene, 8x64 network, 0.116 with oracle 0.898;
    # "feature" 0.898). CLICK_RULE says how it was chosen.
    click_rule: str = CLICK_RULE
    click_radius: int = 1
    # "front" only: the least share of the window's weight a cluster must hold to be chosen
    # for being nearest the camera (trase.prompts.FRONT_SHARE)
    front_share: float = FRONT_SHARE
    # a positive click on a cluster already selected: "nothing" (the paper's), or "next": the
    # cluster the rule ranks next under it (trase.prompts.ON_SELECTED)
    on_selected: str = "nothing"


@dataclasses.dataclass
class TraseSettings:
    """Everything the TRASE method reads: features, clustering, the filter, clicks, rendering."""

    features: FeatureConfig = dataclasses.field(default_factory=FeatureConfig)
    preset: str = "paper"  # the method's preset these settings start from (paper or cpu)
    clustering: ClusteringSettings = dataclasses.field(default_factory=ClusteringSettings)
    # cosine threshold of the cluster filter; None: no filter (every gaussian keeps its cluster)
    filter_threshold: float | None = 0.9
    prompts: ClickSettings = dataclasses.field(default_factory=ClickSettings)
    alpha_threshold: float = 0.5  # rendered alpha of the selection >= this is the predicted mask
    # "alone": the paper's rule (selected gaussians rendered without the rest); "visible": their
    # weight in the full render (occluded parts excluded), see trase.segment
    render_rule: str = "alone"
    # gaussians whose compositing weight summed over the training images (rendered once more in the fit
    # stage: 200 s on the Neu3D format) is below this take their seen neighbours' features; 0: off, the paper's
    unseen_min_weight: float = 0.0
    unseen_neighbours: int = 16  # how many nearest seen gaussians give an unseen one its feature


TRASE_PRESETS = PresetTable("trase", TraseSettings, nested={"features": FEATURE_PRESETS}, error=MethodError)

TRASE_PRESETS.declare("paper", help="the paper's settings per benchmark (its Sec. 4 and public configs)", preset="paper")
# Np (pixels sampled per image) and M' (masks sampled per image) follow the camera rig
TRASE_PRESETS.declare("paper", {"features.n_pixels": 5000, "features.n_masks": 25.0}, when=MONOCULAR)
TRASE_PRESETS.declare("paper", {"features.n_pixels": 10000, "features.n_masks": 50.0}, when=MULTIVIEW)
# the similarity filter's cosine threshold, the paper's per benchmark
TRASE_PRESETS.declare("paper", when=dataset("nerfds"), filter_threshold=0.4)
TRASE_PRESETS.declare("paper", when=dataset("hypernerf"), filter_threshold=0.9)
TRASE_PRESETS.declare("paper", when=dataset("neu3d"), filter_threshold=0.98)
TRASE_PRESETS.declare("paper", when=dataset("immersive"), filter_threshold=0.6)
TRASE_PRESETS.declare("paper", when=dataset("technicolor"), filter_threshold=0.9)
TRASE_PRESETS.declare("paper", when=OWN_CAPTURE, filter_threshold=0.9)  # HyperNeRF's and Technicolor's, their median

TRASE_PRESETS.declare("cpu", base="paper", help="minutes on two cores: the cpu feature preset, Np 2000, every gaussian "
                      "clustered, one filter threshold", preset="cpu")
# Np capped (trase.feature_config.CPU_MAX_PIXELS: 2000 on either rig)
TRASE_PRESETS.declare("cpu", {"features.n_pixels": CPU_MAX_PIXELS})
# The similarity filter: one value for every dataset. Why one value: the paper's thresholds
# (0.4 NeRF-DS ... 0.98 Neu3D) were picked on its own features (10k steps at Np 5000-10000).
# The cpu preset's features (3000 steps at Np <= 2000) put the objects' gaussians at 0.80-0.93
# similarity to their cluster mean (5th percentile) and the other gaussians swept into the same
# clusters at 0.28 (median), 0.41-0.45 (90th percentile): 0.4 keeps floor/wall gaussians, 0.98
# prunes the objects (the earlier 0.98 on 1000-step features kept none of the Neu3D ring: mIoU
# 0.58). The value: chosen on scenes the benchmark never reports (the synthetic scenes of seed 1
# of all five formats, ground-truth geometry), the argmax of the mean mIoU over a grid of feature
# lr {0.025, 0.05, 0.1} x filter {0.6, 0.7, 0.8, 0.9} x min_cluster_size {10, 25, 50}
# (docs/notes/cpu-constants.md): lr 0.1, filter 0.7, min_cluster_size 25 on a 5000 sample,
# mean 0.9437; the previous constants (lr 0.05, filter 0.8, 25, set on the seed-0 scenes' test
# views) rank 6th at 0.9427. The top eight settings lie within 0.0012: min_cluster_size is the
# setting that matters (50 on a 5000 sample lost the Immersive ball to a larger cluster; 10 split
# objects).
TRASE_PRESETS.declare("cpu", filter_threshold=0.7)
# HDBSCAN over every gaussian of a cpu-preset geometry (at most CPU_MAX_GAUSSIANS), not 2% with
# a 5000 floor, with min_cluster_size 50. Why: with a 5000-point sample, min_cluster_size 25 asks
# an object for ~75 gaussians; a small one falls below it, joins a larger cluster, and the
# similarity filter then drops it (the built-in HyperNeRF scene written as a COLMAP capture: its
# ball, 72 gaussians, 58 of them in a 627-gaussian cluster; IoU of its click 0.001, 0.909
# clustering all of them). On the seed-1 scenes (docs/notes/cpu-constants.md, "Clustering every
# gaussian") 25 on a 5000 sample (the grid's choice above) and 50 on all gaussians tie (mean
# 0.9214 against 0.9213 over the five reconstructed and the two monocular ground-truth
# geometries, every scene within 0.001); 25 on all gaussians split an object on the NeRF-DS
# ground truth (0.973 -> 0.960). Cost: 2 s -> 6 s at 15k gaussians.
TRASE_PRESETS.declare("cpu", {"clustering.min_sample": CPU_MAX_GAUSSIANS, "clustering.params.min_cluster_size": 50})
# The render rule: "visible" on a monocular rig. Why: reconstructed from one moving camera on
# CPU, the objects' gaussians reach beyond their outlines where the background hides them (depth
# along the rays is weakly constrained); rendered alone, the halo becomes prediction. Seed-1
# scenes (never reported), cpu geometry, truth-labelled gaussians, test views: false positives
# of 14% (HyperNeRF format) and 40% (NeRF-DS) of the objects' pixels under "alone", 4% and 16%
# under "visible"; the method's mIoU 0.687 -> 0.792 (NeRF-DS format), 0.841 -> 0.890
# (HyperNeRF). On multi-view rigs "visible" did not help (Neu3D 0.907 -> 0.908, Immersive 0.950
# -> 0.938, Technicolor 0.970 -> 0.964), so they keep the paper's rule (docs/notes/cpu-constants.md,
# "The render rule").
TRASE_PRESETS.declare("cpu", when=MONOCULAR, render_rule="visible")
# The feature stage stops once converged (trase.convergence): every 250 steps the objective's
# loss on the training views held out for it (every 10th), on fixed samples; two checks in a row
# without a fall of 1% of the first check's loss end it (the 3000 steps above stay the cap).
# Chosen on the seed-1 scenes of the five formats, ground-truth geometry (docs/notes/skip.md,
# "Stages that stop when converged"): it stopped at 1000-1500 steps, the stage took 0.34-0.56x of
# its time, and mIoU moved by -0.0033 to +0.0000 against the full 3000 steps. The reconstruction
# keeps its schedule: its held-out PSNR still rises at 4000 iterations.
TRASE_PRESETS.declare("cpu", {"features.stop_interval": 250, "features.stop_patience": 2,
                              "features.stop_min_delta": 0.01})
# Scenes of small images: the tiny synthetic scenes' test views hold 1,728-3,072 px (48 x 36 to
# 64 x 48), the small scenes' 12,288-19,200 px (128 x 96 to 160 x 120); nothing between was
# measured, and 10,000 lies between.
TINY_IMAGES = images_below(10_000)
# There the gaussians drawn into almost no training pixel take their seen neighbours' features
# before clustering (trase.unseen). Why: about half of a tiny scene's gaussians sum a compositing
# weight under 0.5 over the training views, their features stay near their random start and the
# clusters mix the objects with the floor and walls. Chosen on the seed-1 tiny scenes of all
# five formats, ground-truth geometry: mIoU 0.798 -> 0.856 (NeRF-DS format), 0.827 -> 0.879
# (HyperNeRF), 0.533 -> 0.559 (Neu3D), 0.460 -> 0.494 (Immersive), 0.605 -> 0.696
# (Technicolor). Not on larger images: on the small monocular scenes 3-5% of the gaussians are
# that unseen and the seed-1 scenes' clusters do not change, and the weights cost a render of
# every training image (200 s on the Neu3D format) (docs/notes/corrective-clicks.md).
TRASE_PRESETS.declare("cpu", when=TINY_IMAGES, unseen_min_weight=0.5)
# ... and render the selection by its weight in the full render (render_rule "visible") on every
# rig, as the monocular rigs do above. Why: on the tiny multi-view scenes (48 x 36 and 64 x 34
# px test views) the objects' gaussians rendered alone are predicted on 0.41-0.62 px outside the
# ground truth for each pixel inside it (parts hidden behind other objects, and their extent at
# this size). Chosen on the seed-1 tiny scenes of the multi-view formats, ground-truth geometry,
# with the rule above: mIoU 0.559 -> 0.584 (Neu3D format), 0.494 -> 0.599 (Immersive), 0.696 ->
# 0.840 (Technicolor); on their small scenes "visible" did not help (the render rule's note above).
TRASE_PRESETS.declare("cpu", when=TINY_IMAGES, render_rule="visible")
# ... and a positive click on a cluster already selected adds the cluster ranked next under it
# (prompts.on_selected "next"). Why: at 3-6 views of 64 x 48 px an object lies in several clusters
# that share its pixels; the robot user clicks again where the object is still missing, and
# "nothing" spends the click. Chosen on the seed-1..3 tiny scenes, ground-truth geometry: mIoU
# 0.786 -> 0.844 (NeRF-DS format, seed 2), 0.743 -> 0.807 (seed 3), 0.866 -> 0.897 (HyperNeRF
# format, seed 3), each its oracle; the other five monocular and the three seed-1 multi-view
# scenes the same (docs/notes/corrective-clicks.md, "A click on a selected cluster").
TRASE_PRESETS.declare("cpu", {"prompts.on_selected": "next"}, when=TINY_IMAGES)
# ... and on a monocular rig TRASE's objective reads the soft correspondence (C = shared
# masks over the masks covering either pixel, trase.objectives.base.mask_jaccard), the paper's
# proposal for small objects that a larger mask also covers. Why: with 3-6 views of 64 x 48 px
# the masks that merge a small object with the floor around it weigh as much as those that
# separate it (the seed-0 NeRF-DS format's ring: merged in 2 of 6 views, dropped in 2), and the
# binary C reads them as "the same object". Chosen on the seed-1..3 tiny monocular scenes, ground-truth geometry: mIoU 0.856 ->
# 0.915, 0.844 -> 0.897, 0.807 -> 0.902 (NeRF-DS format), 0.879 -> 0.877, 0.878 -> 0.899, 0.897
# -> 0.901 (HyperNeRF), each its oracle. Not on the multi-view rigs: their seed-1 tiny scenes lost
# (Neu3D format 0.584 -> 0.511, Technicolor 0.840 -> 0.814; Immersive 0.599 -> 0.624)
# (docs/notes/corrective-clicks.md, "A soft correspondence"). Chosen on TRASE's loss: the other
# objectives on this pipeline (the ablations, CGC, OpenGaussian, plugins) keep their own.
TRASE_PRESETS.declare("cpu", {"features.objective_params.correspondence": "jaccard"},
                      when=TINY_IMAGES & MONOCULAR & objective("trase"))


def trase_settings(preset: str, dataset: str | None, monocular: bool = True) -> TraseSettings:
    """TRASE's settings under ``preset`` for benchmark ``dataset`` (None: a capture of one's
    own on this rig), read from the table without importing the method (torch): for light
    commands such as ``datasets``. A run resolves them through ``Method.resolve_settings``."""
    from benchmark.datasets.registry import get_dataset

    if dataset is not None:
        monocular = get_dataset(dataset).monocular
    return TRASE_PRESETS.resolve(preset, Context(dataset=dataset, monocular=monocular)).config


__all__ = ["CLICK_RULE", "TINY_IMAGES", "TRASE_PRESETS", "ClickSettings", "ClusteringSettings", "TraseSettings", "trase_settings"]
