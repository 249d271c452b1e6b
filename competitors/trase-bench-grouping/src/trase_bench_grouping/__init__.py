"""Identity classification from tracked masks as trase-bench methods (docs/competitors.md).

``gaussian-grouping`` (Ye et al.): a learned 16-d identity encoding per gaussian, rendered and
classified per pixel into the track ids of video masks; ``sa4d``: the identity encoding is a
field of the canonical position and time (an MLP), so a gaussian's class may change over time.
Registered by entry points (pyproject.toml), imported only when used.
"""

__version__ = "0.1.0"
