"""The benchmark's protocol beside the scores (benchmark.scoring): the automatic clicks from the
ground truth (``prompts``), the oracle's clusters (``oracle``) and the geometry's label
ceiling (``ceiling``). The method library (trase) knows none of them."""
