"""Other feature-learning objectives behind the same interface as TRASE's.

Importing this package registers them with ``trase.objectives`` (``get_objective(name)``):

``trase-hard``    TRASE's pair loss over only the individually violating pairs (hard_mining)
``trase-all``     TRASE's pair loss with every pixel an anchor (all_mining)
``cgc``           Contrastive Gaussian Clustering, Silva et al. 2024 (cgc)
``opengaussian``  OpenGaussian's stage-1 instance-feature loss, Wu et al. 2024 (opengaussian)

``cgc_inference`` holds CGC's own selection (similarity threshold to a clicked query feature,
no clustering); it renders, so it is imported on use, not here.
"""

from baselines.all_mining import AllMining, all_mining_loss
from baselines.cgc import (
    ContrastiveGaussianClustering,
    cgc_2d_loss,
    cgc_labels,
    cgc_loss,
    cgc_spatial_loss,
    min_mask_pixels_for,
)
from baselines.hard_mining import HardMining, hard_mining_loss, hard_pairs
from baselines.opengaussian import OpenGaussianObjective, opengaussian_loss

BASELINE_OBJECTIVES = ("trase-hard", "trase-all", "cgc", "opengaussian")

__all__ = [
    "BASELINE_OBJECTIVES",
    "AllMining",
    "ContrastiveGaussianClustering",
    "HardMining",
    "OpenGaussianObjective",
    "all_mining_loss",
    "cgc_2d_loss",
    "cgc_labels",
    "cgc_loss",
    "cgc_spatial_loss",
    "hard_mining_loss",
    "hard_pairs",
    "min_mask_pixels_for",
    "opengaussian_loss",
]
