r"""Whether a test record repeats the training record sample for sample.

A test record read from another file (or handed over from memory) may still be the
training data: a copy of its file under another name, or a part of it cut out and saved.
Its figures, and the diagnosis's choices made on it, would then be on data the fit saw.
Measured samples carry noise, so a stretch of :data:`WIDTH` consecutive samples (every
output and input) that appears verbatim in both records is a copy, not a coincidence;
stretches where the first output does not move (a sensor at rest, a quantised record
between steps) are not looked up, as two records may share them by chance.
"""

from __future__ import annotations

import numpy as np

from cvxid.data.experiment import Experiment

WIDTH = 8
"""Consecutive samples a stretch must share, every column of it, to count as copied."""

PROBES = 200
"""Test stretches looked up in the training record (evenly spaced over the moving ones)."""

SPREAD = 20
"""Evenly spaced test stretches a probe is chosen among (:data:`SPREAD` times
:data:`PROBES`, those whose first output moves)."""


def copied_share(train: Experiment, test: Experiment) -> float:
    r"""The share of ``test``'s moving stretches (:data:`PROBES` of them, :data:`WIDTH`
    samples each, every output and input of ``test`` that ``train`` has too) that appear
    sample for sample in ``train``; 0 when the records share no output or ``test`` never
    moves.  Each probe's first value is looked up in the training record's first output
    sorted once (every position holding it, a quantised record's many too), and the
    candidates are narrowed sample by sample, then column by column."""
    names = [("output", c) for c in test.outputs if c in train.outputs]
    names += [("input", c) for c in test.inputs if c in train.inputs]
    if not names or names[0][0] != "output" or min(train.n, test.n) < WIDTH:
        return 0.0
    a = [getattr(train, kind)(c) for kind, c in names]
    b = [getattr(test, kind)(c) for kind, c in names]
    starts = np.unique(np.linspace(0, test.n - WIDTH, SPREAD * PROBES).round().astype(int))
    windows = b[0][starts[:, None] + np.arange(WIDTH)]
    starts = starts[(np.ptp(windows, axis=1) > 0) & np.isfinite(windows).all(axis=1)]  # (NaN: a gap)
    if not starts.size:
        return 0.0
    probes = starts[np.linspace(0, starts.size - 1, min(PROBES, starts.size)).round().astype(int)]
    order = np.argsort(a[0], kind="stable")
    copied = 0
    for i in probes:
        low, high = np.searchsorted(a[0], b[0][i], "left", order), np.searchsorted(a[0], b[0][i], "right", order)
        candidates = order[low:high]
        candidates = candidates[candidates <= train.n - WIDTH]
        for column_a, column_b in zip(a, b):
            for k in range(WIDTH):
                if not candidates.size:
                    break
                candidates = candidates[column_a[candidates + k] == column_b[i + k]]
        copied += bool(candidates.size)
    return copied / probes.size
