"""The text protocol: each sequence's phrases, found in its test views, lifted to clusters.

``prompts_text.json`` maps a sequence to its phrases, one per object of interest::

    {"americano": ["the cup"], "synthetic": ["the ball", "the ring", "the blob"]}

For each phrase the text-to-mask model (``masks.text``) scores up to SEARCH_VIEWS test views
spread over the sequence (benchmark.protocol.text_choice), each rendered by the method's
geometry (the paper's "in the novel view"); the best one's mask is lifted to clusters
(``trase.prompts.mask_to_clusters``, the protocol's rule) and the union of every phrase's
clusters is rendered at every test view.

``ground-truth`` stands in for the detector (the named object's box in the scene's instance
maps, scored by its visible area) and for the segmenter (the object's instance pixels inside the
box) on synthetic scenes: with both it measures the lifting alone.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from benchmark.errors import UserError
from masks.text import Detection, TextSegmenter

TEXT_FILE = "prompts_text.json"
GROUND_TRUTH = "ground-truth"


def read_phrases(path: Path, sequence: str, aliases: tuple[str, ...] = ()) -> list[str]:
    """The phrases of ``sequence`` (or its first alias the file names) in a prompts_text.json; a
    missing file, bad JSON or a sequence without phrases is a one-line error naming the file."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no text prompts file (prompts.source=text reads {TEXT_FILE}: sequence -> phrases)")
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: not readable JSON ({exc})") from None
    name = next((n for n in (sequence, *aliases) if isinstance(doc, dict) and n in doc), sequence)
    phrases = doc.get(name) if isinstance(doc, dict) else None
    if not isinstance(phrases, list) or not phrases or not all(isinstance(p, str) and p.strip() for p in phrases):
        raise UserError(f"{path}: no phrases for sequence {sequence!r} (expected a list of non-empty strings)")
    return [" ".join(p.split()) for p in phrases]


def phrases_for_objects(names: list[str]) -> list[str]:
    """The phrases a built-in scene's file holds: "the <name>" for each object of interest."""
    return [f"the {n}" for n in names]


class _TruthModel:
    """The ground-truth stand-ins for one test view: the named object's box (score: its share
    of the view) and its instance pixels inside a box."""

    def __init__(self, truth, view_name: str) -> None:
        from masks.generate import read_instance_map

        if view_name not in truth.instance_maps:
            raise UserError(f"{truth.manifest_path}: no instance map of view {view_name!r}")
        self.ids = read_instance_map(truth.instance_maps[view_name])  # [H, W] instance ids
        self.by_name = {o.name: o.id for o in truth.objects}

    def _object(self, phrase: str) -> int:
        words = set(phrase.lower().split())
        named = [i for n, i in self.by_name.items() if n.lower() in words]
        return named[0] if named else -1

    def detect(self, image: np.ndarray, phrase: str) -> list[Detection]:
        pix = self.ids == self._object(phrase)
        if not pix.any():
            return []
        rows, cols = np.nonzero(pix)
        box = (float(cols.min()), float(rows.min()), float(cols.max() + 1), float(rows.max() + 1))
        return [Detection(box, float(pix.mean()))]

    def segment(self, image: np.ndarray, box) -> np.ndarray:
        x0, y0, x1, y1 = (round(float(v)) for v in box)
        inside = np.zeros(self.ids.shape, bool)
        inside[y0:y1, x0:x1] = True
        return inside & (self.ids > 0) & _same_object(self.ids, inside)


def _same_object(ids: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """The pixels of the id most common inside the box (the object the box was drawn around)."""
    values, counts = np.unique(ids[inside & (ids > 0)], return_counts=True)
    return ids == values[np.argmax(counts)] if values.size else np.zeros(ids.shape, bool)


@dataclasses.dataclass
class TextModel:
    """The protocol's text-to-mask model per test view: a learned one (the same for every view)
    or the ground-truth stand-ins (per view)."""

    protocol: object  # benchmark.protocol.settings.PromptProtocol
    scene: object
    _learned: TextSegmenter | None = None
    _by_view: dict = dataclasses.field(default_factory=dict)  # view name -> its TextSegmenter, built once

    def __post_init__(self) -> None:
        p = self.protocol
        uses_truth = GROUND_TRUTH in (p.text_detector, p.text_segmenter)
        if uses_truth and self.scene.truth is None:
            raise UserError(f"prompts.text_detector/segmenter={GROUND_TRUTH}: only synthetic scenes have ground truth "
                            f"({self.scene.dataset}/{self.scene.sequence} has none)")

    def for_view(self, view_name: str) -> TextSegmenter:
        if view_name not in self._by_view:
            self._by_view[view_name] = self._segmenter(view_name)
        return self._by_view[view_name]

    def _segmenter(self, view_name: str) -> TextSegmenter:
        p = self.protocol
        truth = (_TruthModel(self.scene.truth, view_name)
                 if GROUND_TRUTH in (p.text_detector, p.text_segmenter) else None)
        learned = None
        if p.text_detector != GROUND_TRUTH or p.text_segmenter != GROUND_TRUTH:
            learned = self._learned = self._learned or self._load()
        det = truth if p.text_detector == GROUND_TRUTH else learned.detector
        seg = truth if p.text_segmenter == GROUND_TRUTH else learned.segmenter
        # the stand-in scores by visible area, not confidence: any visible object is found
        return TextSegmenter(det, seg, 0.0 if det is truth else p.text_min_score)

    def _load(self) -> TextSegmenter:
        from masks.text import TextModels

        p = self.protocol
        det = p.text_detector if p.text_detector != GROUND_TRUTH else TextModels().detector
        seg = p.text_segmenter if p.text_segmenter != GROUND_TRUTH else TextModels().segmenter
        return TextSegmenter.load(TextModels(det, seg, p.text_min_score), progress=False)

    def label(self) -> str:
        p = self.protocol
        rule = {"share": f"share >= {p.text_min_share}", "cover": f"cover >= {p.text_min_cover}",
                "iou": "the clusters of best IoU"}[p.text_rule]
        return f"text ({p.text_detector} boxes, {p.text_segmenter} masks, lifted by {rule})"


def phrases_file(protocol, scene) -> Path:
    """The prompts_text.json a run reads: prompts.text_file, else the sequence folder's."""
    return Path(protocol.text_file) if protocol.text_file else Path(scene.root) / TEXT_FILE


def scene_phrases(protocol, scene) -> tuple[list[str], str]:
    """(the sequence's phrases, where they came from). A synthetic scene generated before its
    folder held a prompts_text.json takes them from its manifest by the generator's own rule
    (``phrases_for_objects``)."""
    path = phrases_file(protocol, scene)
    if not path.is_file() and not protocol.text_file and scene.truth is not None:
        names = [o.name for o in scene.truth.objects if o.of_interest]
        return phrases_for_objects(names), f"{scene.truth.manifest_path} (objects of interest)"
    aliases = (scene.truth.name,) if scene.truth is not None and scene.truth.name else ()
    return read_phrases(path, scene.sequence, aliases), str(path)


def text_selection(fitted, scene, protocol) -> tuple[list[int], list[dict]]:
    """(the clusters every phrase's mask selects, one record per phrase) for a fitted cluster
    method on a benchmark scene; a phrase that matches nothing selects nothing, and says so."""
    from benchmark.protocol.text_choice import rendered_views, text_choice
    from masks.text import TextPromptError
    from trase.edit import EditableModel

    phrases, _ = scene_phrases(protocol, scene)
    text_model = TextModel(protocol, scene)
    model = EditableModel(fitted.gaussians, fitted.deformation, fitted.labels, fitted.keep)
    views = [(v.name, v.camera) for v in scene.test]
    index = {name: i for i, (name, _) in enumerate(views)}
    image_of = rendered_views(model)  # each view rendered once for every phrase
    chosen, records = set(), []
    for phrase in phrases:
        try:
            c = text_choice(model, views, phrase, text_model.for_view, rule=protocol.text_rule, image_of=image_of,
                            min_share=float(protocol.text_min_share), min_cover=float(protocol.text_min_cover))
        except TextPromptError as exc:
            records.append({"phrase": phrase, "view_index": None, "clusters": [], "note": str(exc)})
            continue
        chosen |= set(c.clusters)
        records.append({"view_index": index[c.view], **c.to_dict()})
    return sorted(chosen), records


__all__ = ["GROUND_TRUTH", "TEXT_FILE", "TextModel", "phrases_file", "phrases_for_objects",
           "read_phrases", "scene_phrases", "text_selection"]
