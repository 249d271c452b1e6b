"""Differentiable 3D gaussian rasterizer: torch reference, numba CPU and gsplat CUDA backends.

    from trase.render import rasterize, pixel_weights, RenderOutput, PixelWeights
"""

from trase.camera import NEAR_PLANE
from trase.render.rasterize import BACKENDS, pixel_weights, rasterize
from trase.render.types import PixelWeights, RenderError, RenderOutput

__all__ = ["BACKENDS", "NEAR_PLANE", "PixelWeights", "RenderError", "RenderOutput", "pixel_weights", "rasterize"]
