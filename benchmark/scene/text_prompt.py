"""Text prompts on a scene: the phrase's 2D mask in a rendered view, lifted to clusters.

The paper's text prompt: a grounded detector and SAM make a 2D mask from the text in a novel
view; the mask's pixels are lifted with the rendered depth to their nearest gaussians and the
clusters hit are chosen (``trase.prompts.mask_to_clusters``: rule ``share`` is the paper's,
``cover`` the clusters the mask covers). Without a named view the detector looks at up to
SEARCH_VIEWS views spread over the scene and the best-scoring one is used (and said).
"""

from __future__ import annotations

import dataclasses

from benchmark.errors import UserError

SEARCH_VIEWS = 8  # views the detector scores when no view is named


@dataclasses.dataclass
class TextChoice:
    """What one phrase chose: the view, the detector's box and score, the clusters, the rule."""

    phrase: str
    view: str
    box: tuple[float, float, float, float]
    score: float
    clusters: list[int]
    rule: str
    mask_pixels: int

    def to_dict(self) -> dict:
        return {"phrase": self.phrase, "view": self.view, "box": [round(float(v), 1) for v in self.box],
                "score": round(float(self.score), 4), "clusters": list(self.clusters), "rule": self.rule,
                "mask_pixels": int(self.mask_pixels)}

    def line(self) -> str:
        return (f"{self.phrase!r}: view {self.view} (score {self.score:.2f}), {self.mask_pixels} px -> clusters "
                f"{self.clusters or 'none'} by {self.rule}")


def search_views(views: list, view: str | None) -> list:
    """The (name, camera) pairs the detector scores: the named view, else up to SEARCH_VIEWS
    spread evenly over ``views``."""
    if view is not None:
        names = [n for n, _ in views]
        if view not in names:
            raise UserError(f"--text-view {view!r}: no such view (e.g. {', '.join(names[:3])})")
        return [views[names.index(view)]]
    step = max(1, -(-len(views) // SEARCH_VIEWS))
    return list(views[::step])[:SEARCH_VIEWS]


def text_choice(model, views: list, phrase: str, segmenter, view: str | None = None,
                rule: str = "cover", image_of=None) -> TextChoice:
    """``phrase`` -> the clusters of ``model`` (a trase.edit.EditableModel) its mask selects in
    the best-scoring of ``views`` [(name, camera)]. ``image_of(name, camera)`` gives the image the
    detector sees (default: the model rendered there)."""
    from masks.text import TextPromptError
    from trase.prompts import mask_to_clusters

    if image_of is None:
        from trase.visualize import Painter

        painter = Painter(model)
        image_of = lambda name, cam: painter.render(cam, "rgb")  # noqa: E731 - the default image
    best = None
    candidates = search_views(views, view)
    for name, cam in candidates:
        image = image_of(name, cam)
        det = segmenter.best(image, phrase)
        if det is not None and (best is None or det.score > best[0].score):
            best = (det, name, cam, image)
    if best is None:
        shown = ", ".join(n for n, _ in candidates[:4]) + (" ..." if len(candidates) > 4 else "")
        raise TextPromptError(f"--text {phrase!r}: nothing matches in view(s) {shown} (no box scored >= "
                              f"{segmenter.min_score}); try another phrase or --text-view")
    det, name, cam, image = best
    found = segmenter.mask_of(image, phrase, det, where=f"view {name}")
    ks = mask_to_clusters(model.gaussians, model.deformation, cam, found.mask, model.labels, rule=rule)
    return TextChoice(found.phrase, name, det.box, det.score, ks, rule, int(found.mask.sum()))


@dataclasses.dataclass(frozen=True)
class TextRequest:
    """The command line's text prompts: phrases, an optional view, the lifting rule, the models
    (None: masks.text's defaults)."""

    phrases: tuple[str, ...] = ()
    view: str | None = None
    rule: str = "cover"
    detector: str | None = None
    segmenter: str | None = None
    min_score: float | None = None

    def load_segmenter(self):
        """masks.text.TextSegmenter of the models asked for, fetched on first use."""
        from masks.text import MIN_SCORE, TextModels, TextSegmenter

        defaults = TextModels()
        return TextSegmenter.load(TextModels(self.detector or defaults.detector, self.segmenter or defaults.segmenter,
                                             MIN_SCORE if self.min_score is None else float(self.min_score)))

    def choices(self, model, views: list, segmenter=None) -> list[TextChoice]:
        """Each phrase's TextChoice (``segmenter``: a TextSegmenter, else the models loaded)."""
        from trase.prompts import MASK_RULES

        if not self.phrases:
            return []
        if self.rule not in MASK_RULES:
            raise UserError(f"--mask-rule {self.rule!r}: choose one of {', '.join(MASK_RULES)}")
        segmenter = segmenter or self.load_segmenter()
        return [text_choice(model, views, p, segmenter, self.view, self.rule) for p in self.phrases]


__all__ = ["SEARCH_VIEWS", "TextChoice", "TextRequest", "search_views", "text_choice"]
