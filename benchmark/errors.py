"""Errors a user can fix: the CLI prints their one-line message and exits 1, no traceback.

Packages below ``benchmark`` (``trase``, ``masks``) must not import it, so the contract is a
marker rather than a base class: any exception class with ``user_facing = True`` is shown as
``error: <message>``. Its message names the file and the problem on one line.
"""

from __future__ import annotations


class UserError(ValueError):
    """Base for the benchmark's own input errors."""

    user_facing = True


def is_user_error(exc: BaseException) -> bool:
    return bool(getattr(exc, "user_facing", False))
