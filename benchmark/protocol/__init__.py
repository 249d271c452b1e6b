"""The benchmark's protocol beside the scores (benchmark.scoring): the automatic clicks from the
ground truth (``prompts``), the robot user's corrections (``corrective``), the oracle's clusters
(``oracle``), the geometry's label ceiling (``ceiling``), and the text prompts (``text``, the
protocol's; ``text_choice``, one phrase's choice; ``text_request``, the command line's phrases and
models). The method library (trase) knows none of them."""
