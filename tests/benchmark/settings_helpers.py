"""Resolved run settings in their record form (what results.json stores), for tests that read
a whole run config."""

from benchmark.pipeline.settings import capture_settings, run_settings


def resolved_dict(method, spec, variant: str, overrides: dict, image_size=None) -> dict:
    return run_settings(method, spec, variant, overrides, image_size).to_dict()


def capture_dict(method, monocular: bool, capture: dict, overrides: dict, image_size=None) -> dict:
    return capture_settings(method, monocular, capture, overrides, image_size).to_dict()
