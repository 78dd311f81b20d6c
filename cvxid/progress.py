"""Progress bars (tqdm) for loops that can run longer than two seconds.

A bar appears only once its loop has run for :data:`DELAY` seconds, on stderr, when stderr
is a terminal; :func:`set_quiet` (the command line's ``--quiet``) silences every bar.
"""

from __future__ import annotations

import sys

from tqdm import tqdm

DELAY = 2.0
"""Seconds a loop runs before its bar appears (shorter jobs print nothing)."""

_quiet = [False]


def set_quiet(quiet: bool = True) -> None:
    """Silence (``True``) or restore (``False``) every progress bar of cvxid."""
    _quiet[0] = bool(quiet)


def is_quiet() -> bool:
    """Whether :func:`set_quiet` silenced the bars."""
    return _quiet[0]


def progress(iterable=None, desc: str = "", disable: bool = False, total: int | None = None):
    """Wrap ``iterable`` in a progress bar on stderr (off when quiet, when ``disable``, or
    when stderr is not a terminal); without an iterable, a bar to ``update()`` by hand and
    ``close()``."""
    off = disable or _quiet[0] or not sys.stderr.isatty()
    return tqdm(iterable, desc=desc, total=total, disable=off, leave=False, delay=DELAY)
