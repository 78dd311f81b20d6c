r"""The memory a regression build needs, checked against the machine before any work.

Measured with ``cvxid bench --long`` (peak resident memory of ``cvxid run`` on a linear
oscillator, 1 kHz): on windows, whose rows are made a chunk at a time, a run keeps the
record, its velocity and a filter's output, about 50 bytes per sample whatever the library
(1e7 samples: 0.69 GB, of which 0.23 GB is Python and its packages); the paper's whole-record
integrals keep about 90 bytes per sample and column (1e6 samples: 1.9 GB at order 3,
4.6 GB at order 6).  A build estimated above the memory available now is refused unless
the spec says ``[fit] allow_large = true``.

.. math:: \text{bytes} \approx B_0 + n_{\rm samples}\,
   \begin{cases} 60 & \text{windows} \\ 100\,(k + 1) & \text{whole record} \end{cases}
"""

from __future__ import annotations

import os

from cvxid.errors import CvxidError

BASE_BYTES = 0.3e9
"""The interpreter, numpy, scipy and cvxpy."""
WINDOWED_BYTES = 60
"""Bytes per sample on windows (measured 46-50 from 10^6 to 10^7 samples, 2026-11-26)."""
WHOLE_RECORD_BYTES = 100
"""Bytes per sample and column with whole-record integrals (measured 87-96)."""


def needed_bytes(samples: int, columns: int, windowed: bool) -> float:
    """Estimated peak memory of a build (see the module docstring)."""
    per_sample = WINDOWED_BYTES if windowed else WHOLE_RECORD_BYTES * (columns + 1)
    return BASE_BYTES + samples * per_sample


def available_bytes() -> float | None:
    """Memory available to a new allocation now (Linux ``MemAvailable``; else the free
    physical pages; None where neither is known)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(samples: int, columns: int, windowed: bool, allow_large: bool = False) -> None:
    """Refuse a build that would need more memory than the machine has available."""
    need, have = needed_bytes(samples, columns, windowed), available_bytes()
    if allow_large or have is None or need <= have:
        return
    how = "windows" if windowed else f"whole-record integrals of {columns} columns"
    fix = ("decimate or split the record" if windowed else
           'use windows (window = "auto", about 60 bytes per sample whatever the library), or fewer columns')
    raise CvxidError(
        f"{samples:,} samples on {how} need about {need / 1e9:.1f} GB of memory and {have / 1e9:.1f} GB is "
        f"available: {fix}; [fit] allow_large = true tries anyway")
