"""The stages of one ``trase-bench run`` sequence, each a small cached unit.

Order and data flow (``benchmark.runner`` orchestrates; each stage reads ``SequenceRun``
and adds its ``StageRecord``)::

    masks     2D "anything" masks of the training views          <- scene
    geometry  gaussians + deformation (reconstructed, truth, import) <- scene
    features  per-gaussian features (the method's learn)         <- masks, geometry
    fit       clusters + filter (the method's group)              <- features, geometry
    prompts   clicks on the objects of interest                   <- ground truth
    evaluate  predicted masks, scores, oracle, click sets         <- fit, prompts, ground truth
    ceiling   the geometry's label ceiling (synthetic scenes)     <- geometry, ground truth

``config`` resolves the run's config (presets, seeds, --set) once and checks its types;
``record`` turns the stage records into the typed results record (benchmark.results.RunRecord).
``trase-bench fit`` (benchmark.captures.fit) runs masks, geometry, features and fit on a
capture of one's own. A command method (benchmark.methods.command) runs masks and prompts, then
its own stages in ``command``: its input folder, the command, the scores.
"""
