"""Feature-learning objectives: the shared contract (base) and TRASE's soft mining (soft)."""

from trase.objectives.base import (
    OBJECTIVES,
    Objective,
    ObjectiveInputError,
    PairStats,
    PixelSample,
    get_objective,
    norm_regulariser,
    pair_stats,
    pair_weights,
    register_objective,
    regulariser_features,
)

__all__ = [
    "OBJECTIVES",
    "Objective",
    "ObjectiveInputError",
    "PairStats",
    "PixelSample",
    "get_objective",
    "norm_regulariser",
    "pair_stats",
    "pair_weights",
    "register_objective",
    "regulariser_features",
]
