"""Progress bars (tqdm) for loops that can run longer than a second."""

from __future__ import annotations

import sys

from tqdm.auto import tqdm


def progress(iterable, desc: str, disable: bool = False, total: int | None = None):
    """Wrap ``iterable`` in a progress bar on stderr (off when stderr is not a terminal)."""
    return tqdm(iterable, desc=desc, total=total, disable=disable or not sys.stderr.isatty(), leave=False)
