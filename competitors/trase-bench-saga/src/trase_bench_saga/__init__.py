"""SAGA-style segmentation (Cen et al., Segment Any 3D GAussians) as a trase-bench method.

Registered by the entry point in pyproject.toml (group ``trase_bench.methods``, name ``saga``);
trase-bench imports ``trase_bench_saga.method`` only when the method is used or listed.
"""

__version__ = "0.1.0"
