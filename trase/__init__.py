"""TRASE: tracking-free 4D segmentation with Gaussian splatting, as a library.

Knows no dataset; the benchmark package feeds it cameras, images and masks.
"""

__version__ = "0.1.0"
