"""Predictions made outside the benchmark, scored into ordinary runs of kind ``external``.

* ``layout``: where a predictions folder keeps each sequence's masks (the public code's
  ``<sequence>/test/ours_<iteration>/pred_masks/`` or a flat ``<sequence>/<frame>.png``);
* ``evaluate``: ground truth found as ``trase-bench run`` finds it, both metrics, one run per
  sequence (``trase-bench evaluate``).
"""
