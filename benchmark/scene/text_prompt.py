"""The command line's text prompts (``select``, ``edit``, ``view``): phrases, a view, the
lifting rule and the models, each phrase chosen by benchmark.protocol.text_choice."""

from __future__ import annotations

import dataclasses

from benchmark.errors import UserError
from benchmark.protocol.text_choice import TextChoice, rendered_views, text_choice


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
        image_of = rendered_views(model)  # each view rendered once for every phrase
        return [text_choice(model, views, p, lambda _: segmenter, self.view, self.rule, image_of)
                for p in self.phrases]


__all__ = ["TextRequest"]
