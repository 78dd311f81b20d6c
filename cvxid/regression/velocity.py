r"""Velocity estimation, for the terms that need :math:`\dot x` (e.g. :math:`\dot x^3`).

* ``"observer"`` — the paper's nonlinear extended state observer (eqs. 27–28):

  .. math::

      \dot z_1 = z_2 - \beta_1 e,\qquad \dot z_2 = -\beta_2\,\mathrm{fal}(e,\alpha,\delta),
      \qquad e = z_1 - y,

  with :math:`\mathrm{fal}(e) = |e|^\alpha \operatorname{sign} e` for :math:`|e|>\delta`
  and :math:`e/\delta^{1-\alpha}` inside (continuous at :math:`\delta`).  Its state starts at
  the measured position and a local slope, so there is no start-up transient.
* ``"savgol"`` — a Savitzky–Golay derivative (scipy).
* ``"spline"`` — the derivative of a smoothing spline whose smoothness is chosen by
  generalised cross-validation (scipy's ``make_smoothing_spline``).

``velocity = "auto"`` in a spec identifies with each estimator and keeps the least test
error.

**Noise in odd powers.**  With :math:`\hat v = v + e`, :math:`E[\hat v^3] = v^3 +
3\sigma_e^2 v`: the :math:`\dot x^3` column gains a share of the :math:`\dot x` column
and biases the damping :math:`c_1` by :math:`-3\sigma_e^2 c_3`.  The known correction
replaces :math:`\hat v^j` by :math:`\sigma_e^j \mathrm{He}_j(\hat v/\sigma_e)`
(probabilists' Hermite polynomials; unbiased for Gaussian errors independent of
:math:`v`).  We measured it on the paper's example at noise 0.01 (Savitzky–Golay
:math:`\sigma_e` from the filter's coefficients): it changed no estimate visibly (k1 5.45
either way), because the estimators' *smoothing bias* and the low-frequency colour of their
error dominate, not their variance.  cvxid therefore does not apply it; the remedy it
offers for velocity-dependent terms is the output-error polish (:mod:`cvxid.identify.output_error`), which
compares positions only: on that example its delay error is -0.05 % ± 0.8 % (10 seeds).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_smoothing_spline
from scipy.signal import savgol_coeffs, savgol_filter

from cvxid.errors import CvxidError
from cvxid.metrics import noise_level

ESTIMATORS = ("observer", "savgol", "spline")


@dataclass(frozen=True)
class ObserverGains:
    """Gains of the nonlinear extended state observer (the paper's values by default)."""

    beta1: float = 100.0
    beta2: float = 900.0
    alpha: float = 0.5
    delta: float = 0.05


def _fal(e: float, alpha: float, delta: float) -> float:
    if abs(e) > delta:
        return abs(e) ** alpha * (1.0 if e > 0 else -1.0)
    return e / delta ** (1.0 - alpha)


def observer(y: np.ndarray, dt: float, gains: ObserverGains = ObserverGains()) -> np.ndarray:
    """The paper's nonlinear extended state observer, integrated with RK4 between samples
    (the measurement is interpolated linearly inside a step)."""
    b1, b2, a, d = gains.beta1, gains.beta2, gains.alpha, gains.delta
    y = np.asarray(y, dtype=float)
    z1 = float(y[0])
    z2 = float(savgol(y[: min(len(y), 51)], dt)[0])
    out = np.empty_like(y)
    out[0] = z2
    ys = y.tolist()

    def f(z1, z2, yk):
        e = z1 - yk
        return z2 - b1 * e, -b2 * _fal(e, a, d)

    for k in range(len(ys) - 1):
        y0, y1 = ys[k], ys[k + 1]
        ym = 0.5 * (y0 + y1)
        k1 = f(z1, z2, y0)
        k2 = f(z1 + 0.5 * dt * k1[0], z2 + 0.5 * dt * k1[1], ym)
        k3 = f(z1 + 0.5 * dt * k2[0], z2 + 0.5 * dt * k2[1], ym)
        k4 = f(z1 + dt * k3[0], z2 + dt * k3[1], y1)
        z1 += dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        z2 += dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        out[k + 1] = z2
    return out


def savgol_window(y: np.ndarray, polyorder: int = 3) -> int:
    """The longest Savitzky–Golay window whose smoothing residual stays at the noise level
    (the discrepancy principle): longer windows average more noise, but once the residual
    exceeds the noise they start to cut the signal itself.  On a record longer than
    :data:`PIECES` × :data:`PIECE` samples the residual is read on that many pieces spread
    over it (a mean square: the pieces' share of the record tells it as well as the whole;
    10^7 samples took 8 s whole).  Remembered for the last :data:`REMEMBERED` signals (a
    run asks again for the same record many times)."""
    y = np.ascontiguousarray(y, float)
    key = (hashlib.blake2b(y.tobytes(), digest_size=16).digest(), polyorder)
    window = _windows.get(key)
    if window is None:  # (safe in threads: nothing read back that another may evict)
        window = _savgol_window(y, polyorder)
        if len(_windows) >= REMEMBERED:
            _windows.pop(next(iter(_windows), None), None)
        _windows[key] = window
    return window


REMEMBERED = 64
_windows: dict[tuple[bytes, int], int] = {}
PIECES = 8
PIECE = 1 << 16
"""A long record's window is chosen on ``PIECES`` pieces of ``PIECE`` samples (the record
whole up to 2^19 samples)."""


def _savgol_window(y: np.ndarray, polyorder: int) -> int:
    r"""The rule of :func:`savgol_window`: the smoothing residual :math:`r_L` of a window of
    :math:`L` samples, divided by :math:`\sqrt{1 - h_L}` (:math:`h_L` the filter's centre
    weight, the share of a sample's own noise it keeps), is the noise's deviation while the
    window only averages noise, and grows once it cuts the signal.  The window grows (by
    a quarter) while that stays within 2 % of the larger of :func:`noise_level` and the
    median reading so far (this one's included): it stops where the readings leave their
    plateau, not where one first exceeds the estimate (the shortest windows' readings
    scatter by a few %).  (:func:`noise_level`, a median, alone scatters by
    about 3 %: 5 % low, it stopped the rule at 51 samples for 373 on 2 of 40 white-noise
    records, their velocity error 14 times the median's.)"""
    n = len(y)
    pieces = [y] if n <= PIECES * PIECE else [y[a:a + PIECE] for a in np.linspace(0, n - PIECE, PIECES).astype(int)]
    size = sum(p.size for p in pieces)

    def noise(length):  # the noise's deviation as the window's residual reads it
        square = sum(np.sum((p - savgol_filter(p, length, polyorder, mode="interp")) ** 2) for p in pieces)
        return np.sqrt(square / size / (1 - savgol_coeffs(length, polyorder)[length // 2]))

    sigma, best, limit = noise_level(y), polyorder + 2 | 1, min(p.size for p in pieces) // 4
    if best >= limit:
        return best
    readings = [noise(best)]
    length = int(best * 1.25) | 1
    while length < limit:
        readings.append(noise(length))
        if readings[-1] > 1.02 * max(sigma, float(np.median(readings))):
            break
        best = length
        length = int(length * 1.25) | 1
    return best


def savgol(y: np.ndarray, dt: float, window: float | None = None, polyorder: int = 3) -> np.ndarray:
    """Savitzky–Golay derivative; ``window`` in seconds (default: chosen from the noise by
    :func:`savgol_window`)."""
    n = len(y)
    length = savgol_window(y, polyorder) if window is None else int(round(window / dt)) | 1
    length = max(polyorder + 2 | 1, min(length, n - (1 - n % 2)))
    return savgol_filter(np.asarray(y, float), length, polyorder, deriv=1, delta=dt, mode="interp")


def spline(y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Derivative of a GCV smoothing spline."""
    return make_smoothing_spline(np.asarray(t, float), np.asarray(y, float)).derivative()(t)


ROUNDOFF = 1e-9
"""An estimated velocity within this share of its record's largest is round-off, read as
0 (:func:`at_rest`)."""


def at_rest(v: np.ndarray) -> np.ndarray:
    r"""``v`` with the values within :data:`ROUNDOFF` of its largest set to 0.  A
    Savitzky–Golay derivative of a still stretch, a quantised sensor's level samples, is
    zero but for round-off (:math:`\sim 10^{-12}` of the motion), and a sign of it, a
    friction's column, read the round-off (the spline's and the observer's derivatives of
    a still stretch are not round-off, but their far tails, 1e-9 of the motion, are as good
    as rest): a ninth outside check's unbalanced disk, its record written
    with 10 digits instead of 17 (the angles 5e-10 rad apart, the encoder's step 3e-3),
    flipped the sign of 5–87 still samples and the diagnosis chose other terms."""
    v = np.asarray(v, float)
    finite = np.abs(v[np.isfinite(v)])
    if finite.size == 0:
        return v
    return np.where(np.abs(v) <= ROUNDOFF * finite.max(), 0.0, v)


def estimate_velocity(y: np.ndarray, t: np.ndarray, method: str, gains: ObserverGains | None = None):
    """Velocity of the measured position ``y`` by the named ``method`` (round-off read as
    rest, :func:`at_rest`)."""
    dt = float(t[1] - t[0])
    estimators = {"observer": lambda: observer(y, dt, gains or ObserverGains()), "savgol": lambda: savgol(y, dt),
                  "spline": lambda: spline(y, t)}
    if method in estimators:
        return at_rest(estimators[method]())
    raise CvxidError(
        f"unknown velocity estimator '{method}'; use one of {', '.join(ESTIMATORS)} "
        "or the name of a measured velocity column"
    )


def initial_state(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Position and velocity at the first sample, from a Savitzky–Golay fit whose window
    is chosen from the noise (a short fixed window lets the noise into the velocity)."""
    w = savgol_window(y)
    dt = float(t[1] - t[0])
    head = np.asarray(y, float)[:w]  # the first sample's fit reads the first window only
    return (float(savgol_filter(head, w, 3, mode="interp")[0]),
            float(savgol_filter(head, w, 3, deriv=1, delta=dt, mode="interp")[0]))
