"""2D "anything" masks: generators, bit-packed storage, sampling rules.

Public API::

    MaskSet                         masks [N,H,W] bool, area [N], score [N]|None, generator, info
    load(path) / save(path, ms)     either format in, ours out (see masks.store)
    save_official(path, ms)         the paper's torch.save(bitarray) format
    to_rle / from_rle, save_coco_json / load_coco_json
    compression_report(ms), format_compression_table(reports)
    mask_path(out_dir, view_name)
    sampling.sample_masks / sampling.sample_pixels
    generators: masks.generators.{sam.SamGenerator, classical.ClassicalGenerator,
                synthetic.SyntheticGenerator}; generate_scene_masks(views, generator, out_dir)
    text.TextSegmenter              a phrase -> a mask (OWLv2 boxes, SAM masks; the text extra)

Generators are imported lazily (OpenCV, segment-anything), so ``import masks`` is light.
"""

from masks import sampling
from masks.coco import from_rle, load_coco_json, save_coco_json, to_rle
from masks.compression import CompressionReport, compression_report, format_compression_table
from masks.maskset import MaskError, MaskSet
from masks.store import MaskFileError, load, loads, mask_path, read_header, save, save_official

__all__ = [
    "CompressionReport", "MaskError", "MaskFileError", "MaskSet", "compression_report",
    "format_compression_table", "from_rle", "generate_scene_masks", "load", "load_coco_json",
    "loads", "mask_path", "read_header", "sampling", "save", "save_coco_json", "save_official",
    "to_rle",
]


def generate_scene_masks(*args, **kwargs):
    """See ``masks.generate.generate_scene_masks`` (imported on first use)."""
    from masks.generate import generate_scene_masks as _impl

    return _impl(*args, **kwargs)
