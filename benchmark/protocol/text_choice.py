"""A phrase's choice in a scene: its 2D mask in the best-scoring of some views, lifted to
clusters. What ``select``/``edit``/the viewer (benchmark.protocol.text_request) and the text protocol
(benchmark.protocol.text) share.

The paper's text prompt: a grounded detector and SAM make a 2D mask from the text in a novel
view; the mask's pixels are lifted with the rendered depth to their nearest gaussians and the
clusters hit are chosen (``trase.prompts.mask_to_clusters``: rule ``share`` is the paper's,
``cover`` the clusters the mask covers, ``iou``, the default, the clusters that best match it). Without a named view the detector looks at up to
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


def rendered_views(model):
    """``image_of(name, camera)``: ``model`` rendered there, each view once however many phrases
    look at it."""
    from trase.visualize import Painter

    painter, images = Painter(model), {}

    def image_of(name: str, camera):
        if name not in images:
            images[name] = painter.render(camera, "rgb")
        return images[name]

    return image_of


def text_choice(model, views: list, phrase: str, segmenter_of, view: str | None = None,
                rule: str | None = None, image_of=None, **rule_args) -> TextChoice:
    """``phrase`` -> the clusters of ``model`` (a trase.edit.EditableModel) its mask selects in
    the best-scoring of ``views`` [(name, camera)]. ``segmenter_of(name)`` gives the
    masks.text.TextSegmenter of a view (one for all, or a per-view stand-in); ``image_of(name,
    camera)`` the image it sees (default: ``rendered_views(model)``); ``rule``: of
    ``mask_to_clusters`` (None: its default); ``rule_args``: its min_cover or min_share."""
    from masks.text import TextPromptError
    from trase.prompts import DEFAULT_MASK_RULE, mask_to_clusters

    rule = rule or DEFAULT_MASK_RULE
    image_of = image_of or rendered_views(model)
    best = None
    candidates = search_views(views, view)
    for name, cam in candidates:
        image, segmenter = image_of(name, cam), segmenter_of(name)
        det = segmenter.best(image, phrase)
        if det is not None and (best is None or det.score > best[0].score):
            best = (det, name, cam, image, segmenter)
    if best is None:
        shown = ", ".join(n for n, _ in candidates[:4]) + (" ..." if len(candidates) > 4 else "")
        raise TextPromptError(f"--text {phrase!r}: nothing matches in view(s) {shown} (no box scored >= "
                              f"{segmenter.min_score}); try another phrase or --text-view")
    det, name, cam, image, segmenter = best
    found = segmenter.mask_of(image, phrase, det, where=f"view {name}")
    ks = mask_to_clusters(model.gaussians, model.deformation, cam, found.mask, model.labels, rule=rule, **rule_args)
    return TextChoice(found.phrase, name, det.box, det.score, ks, rule, int(found.mask.sum()))


__all__ = ["SEARCH_VIEWS", "TextChoice", "rendered_views", "search_views", "text_choice"]
