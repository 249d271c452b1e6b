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
    rule: str | None = None  # None: trase.prompts.DEFAULT_MASK_RULE
    detector: str | None = None
    segmenter: str | None = None
    min_score: float | None = None

    def load_segmenter(self):
        """masks.text.TextSegmenter of the models asked for, fetched on first use."""
        from masks.text import MIN_SCORE, TextModels, TextSegmenter

        defaults = TextModels()
        return TextSegmenter.load(TextModels(self.detector or defaults.detector, self.segmenter or defaults.segmenter,
                                             MIN_SCORE if self.min_score is None else float(self.min_score)))

    @property
    def mask_rule(self) -> str:
        """The lifting rule asked for, else the library's default."""
        from trase.prompts import DEFAULT_MASK_RULE, MASK_RULES

        rule = self.rule or DEFAULT_MASK_RULE
        if rule not in MASK_RULES:
            raise UserError(f"--mask-rule {rule!r}: choose one of {', '.join(MASK_RULES)}")
        return rule

    def choices(self, model, views: list, segmenter=None) -> list[TextChoice]:
        """Each phrase's TextChoice (``segmenter``: a TextSegmenter, else the models loaded)."""
        if not self.phrases:
            return []
        rule = self.mask_rule
        segmenter = segmenter or self.load_segmenter()
        image_of = rendered_views(model)  # each view rendered once for every phrase
        return [text_choice(model, views, p, lambda _: segmenter, self.view, rule, image_of)
                for p in self.phrases]


__all__ = ["TextRequest"]
