"""The benchmark: datasets, splits, scoring, runner, leaderboards, reports, the CLI."""

__version__ = "0.1.0"
