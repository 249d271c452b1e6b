"""The text-prompt options that ``select`` and ``edit`` share, and the request they make."""

from __future__ import annotations

import click

from trase.prompts import DEFAULT_MASK_RULE, MASK_RULES


def text_model_options(f):
    """--mask-rule, --detector, --segmenter, --min-score: how a phrase becomes clusters."""
    f = click.option("--min-score", type=click.FloatRange(0.0, 1.0), default=None,
                     help="The least detector score a box needs (default 0.1, OWLv2's own).")(f)
    f = click.option("--segmenter", default=None, metavar="HUB_ID|PATH",
                     help="The box-prompted segmenter (default facebook/sam-vit-base, fetched once).")(f)
    f = click.option("--detector", default=None, metavar="HUB_ID|PATH",
                     help="The open-vocabulary detector (default google/owlv2-base-patch16-ensemble, fetched once).")(f)
    f = click.option("--mask-rule", type=click.Choice(MASK_RULES), default=DEFAULT_MASK_RULE, show_default=True,
                     help="How a --mask or --text mask chooses clusters: cover (the clusters it covers), share (the paper's: "
                          "the clusters its lifted pixels' nearest gaussians belong to) or iou (the clusters that "
                          "together best match it).")(f)
    return f


def text_options(f):
    """--text PHRASE (repeatable), --text-view and the text_model_options."""
    f = text_model_options(f)
    f = click.option("--text-view", "--view", "text_view", default=None, metavar="VIEW",
                     help="The view a --text phrase is looked for in (default: the best-scoring of 8 spread views).")(f)
    return click.option("--text", "texts", multiple=True, metavar="PHRASE",
                        help="Select what a phrase names ('the cup'): detector box -> mask -> clusters; repeatable "
                             "(needs the 'text' extra).")(f)


def text_request(mask_rule, detector, segmenter, min_score, texts=(), text_view=None):
    """The options' benchmark.protocol.text_request.TextRequest (no phrases without --text; its
    rule is --mask's too)."""
    from benchmark.protocol.text_request import TextRequest

    return TextRequest(tuple(texts), text_view, mask_rule, detector, segmenter, min_score)
