"""An example trase-bench method from a package of its own (docs/methods.md).

The method is registered by the entry point in pyproject.toml (group ``trase_bench.methods``),
not by importing this package: trase-bench imports ``method`` when the name is used.
"""

__version__ = "0.1.0"
