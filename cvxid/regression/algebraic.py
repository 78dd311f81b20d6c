r"""The algebraic operation: derivatives in ``s`` and division by ``s^m``, in the time domain.

A linear differential term of order :math:`d` of a signal :math:`z` has the Laplace
transform :math:`s^d Z(s) - \sum_{j<d} s^{d-1-j} z^{(j)}(0)`.  The initial conditions form
a polynomial in :math:`s` of degree :math:`d-1`; differentiating :math:`n \ge d` times in
:math:`s` removes it exactly.  Dividing by :math:`s^m` with :math:`m \ge d` leaves only
integrals.  With :math:`d^j/ds^j\,Z(s) \leftrightarrow (-t)^j z(t)` and
:math:`s^{-i} \leftrightarrow \int^{(i)}` (Cauchy's iterated integral from 0),

.. math::

    \mathcal{L}^{-1}\!\left[s^{-m}\frac{d^n}{ds^n}\big(s^d Z(s)\big)\right]
    = \sum_{k=0}^{\min(n,d)} \binom{n}{k}\frac{d!}{(d-k)!}\,(-1)^{n-k}
      \int^{(m-d+k)} t^{\,n-k} z(t),

which for a static term (:math:`d = 0`) is :math:`(-1)^n \int^{(m)} t^n z(t)`.

Two ways to apply it:

* :class:`AlgebraicTransform` on the whole record (the paper's): one row per sample, the
  iterated integrals by repeated cumulative Simpson quadrature (scipy), exact for the
  low-degree polynomials that initial conditions contribute.  Its weights grow like
  :math:`t^{n}` and its integrals like :math:`t^m`: on long records the last rows dominate
  and the scaled design is badly conditioned.
* :class:`WindowedTransform` on sliding windows of length :math:`W` (the default): each row
  is the same operation on one window :math:`[a, a+W]`, evaluated at its end.  Written with
  Cauchy's formula, the row is

  .. math::

      \sum_k f_k \int_0^W \frac{(W-s)^{c_k-1}}{(c_k-1)!}\, s^{p_k}\, z(a+s)\,ds
      = \int_0^W K_d(s)\, z(a+s)\,ds,

  a correlation of the signal with a fixed kernel :math:`K_d` (a modulating function:
  :math:`s^n (W-s)^{m-1}/(m-1)!` and its derivatives).  Initial conditions at every window
  start vanish exactly as for the whole record; every window weighs the same, so long
  records give more rows of the same quality instead of ever larger weights.
* :class:`RestartTransform`: the whole-record operation restarted in consecutive windows
  (rows at every sample).  Its rows are the left-anchored kernels :math:`s^n (\tau-s)^{m-1}`
  of every length :math:`\tau \le W`, a richer family than one sliding kernel: on the
  Silverbox recording (610 Hz, a few samples per period) restart windows of 0.05 s fit
  better than any sliding window; on the random benchmark sliding windows do.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb, factorial
from typing import Callable

import numpy as np
from scipy.integrate import cumulative_simpson
from scipy.signal import correlate

from cvxid.errors import CvxidError

Reader = Callable[[slice | np.ndarray], np.ndarray]
"""A signal read in pieces: ``read(index)`` is its samples at ``index`` (a slice, or an
array of sample numbers), so a long record's term is evaluated a chunk at a time, never
whole."""

CHUNK = 1 << 18
"""Samples a windowed transform reads at once (2 MB a signal): with the windows' own rows,
the memory a column needs does not grow with the record."""
OVERLAP = 4
"""Windows that read their samples more than this many times over (rows × window length
over the samples they span) are correlated by FFT over their chunk; sparser ones are
gathered and multiplied directly."""


@dataclass(frozen=True)
class AlgebraicOrders:
    """How many ``s``-derivatives (``n``) and divisions by ``s`` (``m``) to apply."""

    n: int
    m: int

    @classmethod
    def for_model(cls, model) -> "AlgebraicOrders":
        """The orders of a :class:`~cvxid.model.equation.ModelSpec` (its highest derivative,
        its user's orders)."""
        return cls.for_derivative_order(model.highest_derivative, *model.orders, model.keep_initial_conditions)

    @classmethod
    def for_derivative_order(
        cls, highest: int, n: int | None = None, m: int | None = None, keep_initial_conditions: bool = False
    ):
        """Orders for derivatives up to ``highest``: by default ``n = highest`` (the fewest
        that remove every initial condition) and ``m = n + 1`` (one integration more than
        needed, as in the paper, which filters noise and truncation error: on the paper's
        example it moves the Taylor-3 delay estimate from 0.142 to 0.195); the user's own
        orders are checked.  ``keep_initial_conditions`` admits ``n < highest`` (the
        paper's own choice n = 2 with a third-order Taylor term), for reproducing it only."""
        n = highest if n is None else int(n)
        m = n + 1 if m is None else int(m)
        if n < highest and not keep_initial_conditions:
            raise CvxidError(
                f"algebraic order n = {n} keeps initial-condition terms of the derivative of "
                f"order {highest}; use n >= {highest}"
            )
        if m < highest:
            raise CvxidError(
                f"algebraic order m = {m} leaves a time derivative of order {highest} in the "
                f"regression; use m >= {highest}"
            )
        return cls(n, m)

    def weights(self, d: int) -> list[tuple[float, int, int]]:
        """The (factor, power of t, number of integrals) triples of a term of order ``d``."""
        if d > self.m:
            raise CvxidError(f"derivative order {d} exceeds the algebraic order m = {self.m}")
        return [
            (comb(self.n, k) * factorial(d) / factorial(d - k) * (-1) ** (self.n - k),
             self.n - k, self.m - d + k)
            for k in range(min(self.n, d) + 1)
        ]

    def __str__(self) -> str:
        return f"n = {self.n} s-derivatives, m = {self.m} integrations"


class AlgebraicTransform:
    """Apply the algebraic operation to signals on one uniform time grid.

    Iterated integrals of :math:`t^i z` are cached per signal, so columns that share a
    signal (e.g. the Taylor terms of ``x``) share their integrals.
    """

    def __init__(self, time: np.ndarray, orders: AlgebraicOrders):
        self.t = np.asarray(time, dtype=float) - float(time[0])
        self.dt = float(self.t[-1] / (self.t.size - 1))
        self.orders = orders
        self._cache: dict[tuple[int, int], tuple[np.ndarray, list[np.ndarray]]] = {}

    def integral(self, signal: np.ndarray, power: int, count: int) -> np.ndarray:
        r""":math:`\int^{(count)} t^{power} z(t)`, integrated from the grid's first sample."""
        entry = self._cache.get((id(signal), power))
        if entry is None or entry[0] is not signal:
            entry = (signal, [self.t**power * signal])  # holding the signal keeps its id unique
            self._cache[(id(signal), power)] = entry
        stack = entry[1]
        while len(stack) <= count:
            stack.append(cumulative_simpson(stack[-1], dx=self.dt, initial=0.0))
        return stack[count]

    def clear(self) -> None:
        """Forget the cached integrals (each holds its signal alive)."""
        self._cache.clear()

    def rows(self, read: Reader, d: int = 0) -> np.ndarray:
        """:meth:`column` of the signal that ``read`` gives (read whole: every row of the
        whole-record operation reads the record from its start)."""
        return self.column(read(slice(0, self.t.size)), d)

    def column(self, signal: np.ndarray, d: int = 0) -> np.ndarray:
        """The regression column of ``d``-th derivative of ``signal`` (``d = 0``: static);
        a 2-D ``signal`` is one record on this grid per row."""
        signal = np.asarray(signal, dtype=float)
        out = np.zeros(signal.shape)
        for factor, power, count in self.orders.weights(d):
            out += factor * self.integral(signal, power, count)
        return out


class WindowedTransform:
    """Apply the algebraic operation on sliding windows of ``length`` samples (odd), one
    row every ``stride`` samples: row ``i`` is the operation on samples
    ``[i * stride, i * stride + length)`` evaluated at the window's end.

    The rows are made a chunk of windows at a time (:meth:`rows`): a chunk's windows span at
    most :data:`CHUNK` samples (or two windows), and only the samples they cover are read (at
    most :data:`OVERLAP` times each when gathered), so a long record's column costs the
    memory of a chunk and the time of the samples read, not of the record."""

    def __init__(self, time: np.ndarray, orders: AlgebraicOrders, length: int, stride: int):
        t = np.asarray(time, dtype=float)
        if length % 2 == 0 or length < 5:
            raise CvxidError(f"a window needs an odd number of samples >= 5, got {length}")
        if t.size < length:
            raise CvxidError(f"a window of {length} samples does not fit in {t.size} samples")
        self.dt = float((t[-1] - t[0]) / (t.size - 1))
        self.orders, self.length, self.stride = orders, int(length), int(stride)
        self.starts = np.arange(0, t.size - length + 1, stride)
        self.t = t[self.starts + length - 1]  # each row's time: its window's end
        s = np.arange(length) * self.dt
        simpson = np.ones(length)
        simpson[1:-1:2], simpson[2:-1:2] = 4.0, 2.0
        self._s, self._quadrature = s, simpson * self.dt / 3.0
        self._kernels: dict[int, np.ndarray] = {}
        self.chunks = self._chunked(self.starts, self.length)

    @staticmethod
    def _chunked(starts: np.ndarray, length: int) -> list[tuple[int, int]]:
        """Consecutive runs ``[lo, hi)`` of rows whose windows span at most
        ``max(CHUNK, 2 length)`` samples."""
        span = max(CHUNK, 2 * length)
        chunks, lo = [], 0
        while lo < starts.size:
            hi = int(np.searchsorted(starts, starts[lo] + span - length, side="right"))
            chunks.append((lo, max(hi, lo + 1)))
            lo = chunks[-1][1]
        return chunks

    def kernel(self, d: int) -> np.ndarray:
        r"""The quadrature-weighted kernel :math:`K_d(s_j) q_j` of a term of order ``d``."""
        if d not in self._kernels:
            s, W = self._s, self._s[-1]
            k = np.zeros_like(s)
            for factor, power, count in self.orders.weights(d):
                if count == 0:  # no integral: the signal at the window's end
                    k[-1] += factor * W**power
                else:
                    k += factor * (W - s) ** (count - 1) / factorial(count - 1) * s**power * self._quadrature
            self._kernels[d] = k
        return self._kernels[d]

    def rows(self, read: Reader, d: int = 0) -> np.ndarray:
        r"""The regression column of the ``d``-th derivative of the signal that ``read``
        gives, one value per window, :math:`\sum_j K_d(s_j)\,q_j\, z(a + s_j)`, a chunk
        of windows at a time: overlapping windows correlated by FFT over the samples they
        span, sparse ones (a long record's) gathered, their samples alone read."""
        kernel, length = self.kernel(d), self.length
        out = np.empty(self.starts.size)
        for lo, hi in self.chunks:
            starts = self.starts[lo:hi]
            a, b = int(starts[0]), int(starts[-1]) + length
            if (hi - lo) * length <= OVERLAP * (b - a):
                samples = (starts[:, None] + np.arange(length)).ravel()
                out[lo:hi] = np.asarray(read(samples), dtype=float).reshape(hi - lo, length) @ kernel
            else:
                out[lo:hi] = correlate(np.asarray(read(slice(a, b)), dtype=float), kernel, mode="valid")[starts - a]
        return out

    def column(self, signal: np.ndarray, d: int = 0) -> np.ndarray:
        """The regression column of the ``d``-th derivative of ``signal`` (the whole
        record's samples), one value per window."""
        signal = np.asarray(signal, dtype=float)
        return self.rows(signal.__getitem__, d)


class RestartTransform:
    """Apply the algebraic operation on consecutive windows of ``length`` samples, each
    from its own start (rows at every sample, stacked; a tail shorter than half a window
    is left out).  The whole windows are transformed together, one row of a 2-D array
    each (their integrals one call along the rows: one call a window took the Silverbox's
    delay profile 90 % of its time in scipy's per-call overhead)."""

    def __init__(self, time: np.ndarray, orders: AlgebraicOrders, length: int):
        n = np.asarray(time).size
        self.bounds = [(a, min(a + length, n)) for a in range(0, max(n - length // 2, 1), length)]
        self.whole = sum(b - a == length for a, b in self.bounds)  # (every window but perhaps the last)
        self.length = length
        self.window = AlgebraicTransform(time[:length], orders) if self.whole else None
        self.tail = [AlgebraicTransform(time[a:b], orders) for a, b in self.bounds[self.whole:]]

    def rows(self, read: Reader, d: int = 0) -> np.ndarray:
        """The regression column of the ``d``-th derivative of the signal that ``read``
        gives, window after window (the whole windows read at once, the tail on its own)."""
        parts = []
        if self.whole:
            windows = read(slice(0, self.whole * self.length)).reshape(self.whole, self.length)
            parts.append(self.window.column(windows, d).ravel())
        parts += [p.column(read(slice(a, b)), d) for p, (a, b) in zip(self.tail, self.bounds[self.whole:])]
        for transform in (self.window, *self.tail):  # (each call reads afresh: its integrals are never asked again)
            if transform is not None:
                transform.clear()
        return np.concatenate(parts)

    def column(self, signal: np.ndarray, d: int = 0) -> np.ndarray:
        """The regression column of the ``d``-th derivative of ``signal``, window after window."""
        return self.rows(np.asarray(signal, dtype=float).__getitem__, d)
