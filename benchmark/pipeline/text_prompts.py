"""The evaluate stage under the text protocol (benchmark.protocol.text): the phrases' clusters
rendered at every test view."""

from __future__ import annotations

import hashlib

from benchmark.errors import UserError

TEXT_PROTOCOL_VERSION = 1


def segment_text(method, fitted, scene, protocol) -> tuple[list, list[int], dict]:
    """(masks at every test view, clusters selected, the text record) of a cluster method."""
    from benchmark.protocol.text import TextModel, scene_phrases, text_selection

    if not getattr(method, "selects_clusters", False) or fitted.gaussians is None:
        raise UserError(f"{method.name}: prompts.source=text lifts masks to clusters; this method selects none")
    selected, phrases = text_selection(fitted, scene, protocol)
    preds = method.render_selection(fitted, scene, selected)
    return preds, selected, {"version": TEXT_PROTOCOL_VERSION, "file": scene_phrases(protocol, scene)[1],
                             "detector": protocol.text_detector, "segmenter": protocol.text_segmenter,
                             "rule": protocol.text_rule, "min_share": float(protocol.text_min_share),
                             "min_cover": float(protocol.text_min_cover), "min_score": float(protocol.text_min_score),
                             "label": TextModel(protocol, scene).label(), "phrases": phrases}


def text_key(protocol, scene) -> dict:
    """The text protocol's part of the evaluate stage's key (the phrases by their content)."""
    from benchmark.protocol.text import scene_phrases

    content = hashlib.sha256("\n".join(scene_phrases(protocol, scene)[0]).encode()).hexdigest()[:16]
    return {"text": {"version": TEXT_PROTOCOL_VERSION, "detector": protocol.text_detector,
                     "segmenter": protocol.text_segmenter, "rule": protocol.text_rule,
                     "min_share": float(protocol.text_min_share), "min_cover": float(protocol.text_min_cover),
                     "min_score": float(protocol.text_min_score),
                     "phrases": content}}


__all__ = ["TEXT_PROTOCOL_VERSION", "segment_text", "text_key"]
