r"""Whether a test record repeats the training record sample for sample.

A test record read from another file (or handed over from memory) may still be the
training data: a copy of its file under another name, or a part of it cut out and saved.
Its figures, and the diagnosis's choices made on it, would then be on data the fit saw.
Measured samples carry noise, so a stretch of :data:`WIDTH` consecutive samples (every
output and input) that appears verbatim in both records is a copy, not a coincidence;
stretches where no output moves (a sensor at rest, a quantised record between steps) are
not counted, as two records may share them by chance.
"""

from __future__ import annotations

import numpy as np

from cvxid.data.experiment import Experiment

WIDTH = 8
"""Consecutive samples a stretch must share, every column of it, to count as copied."""

PROBES = 200
"""Test stretches looked up in the training record (evenly spaced over the moving ones)."""

CANDIDATES = 20
"""Training samples with a probe's first output value that are compared with the probe (a
quantised record repeats its values)."""


def copied_share(train: Experiment, test: Experiment) -> float:
    r"""The share of ``test``'s moving stretches (:data:`PROBES` of them, :data:`WIDTH`
    samples each, every output and input of ``test`` that ``train`` has too) that appear
    sample for sample in ``train``; 0 when the records share no column or ``test`` never
    moves."""
    outputs = [c for c in test.outputs if c in train.outputs]
    inputs = [c for c in test.inputs if c in train.inputs]
    if not outputs or min(train.n, test.n) < WIDTH:
        return 0.0
    a = np.column_stack([train.output(c) for c in outputs] + [train.input(c) for c in inputs])
    b = np.column_stack([test.output(c) for c in outputs] + [test.input(c) for c in inputs])
    starts = np.arange(test.n - WIDTH + 1)
    first = b[: test.n - WIDTH + 1, 0]
    moving = np.ptp(np.lib.stride_tricks.sliding_window_view(b[:, 0], WIDTH), axis=1) > 0
    starts = starts[moving & np.isfinite(first)]
    if not starts.size:
        return 0.0
    probes = starts[np.linspace(0, starts.size - 1, min(PROBES, starts.size)).round().astype(int)]
    order = np.argsort(a[:, 0], kind="stable")
    keys = a[order, 0]
    last = train.n - WIDTH
    copied = 0
    for i in probes:
        low, high = np.searchsorted(keys, b[i, 0], "left"), np.searchsorted(keys, b[i, 0], "right")
        window = b[i: i + WIDTH]
        copied += any(np.array_equal(a[j: j + WIDTH], window, equal_nan=True)
                      for j in order[low: min(high, low + CANDIDATES)] if j <= last)
    return copied / probes.size
