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
* :func:`model_smoother` — a Kalman/RTS smoother built on an identified model.

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
offers for velocity-dependent terms is the output-error polish (:mod:`cvxid.polish`), which
compares positions only: on that example its delay error is -0.05 % ± 0.8 % (10 seeds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_smoothing_spline
from scipy.signal import savgol_filter

from .errors import CvxidError

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


def noise_level(y: np.ndarray) -> float:
    """Standard deviation of white measurement noise, from the median absolute third
    difference (smooth signals contribute almost nothing to it at fine sampling)."""
    d3 = np.diff(np.asarray(y, float), 3)
    return float(np.median(np.abs(d3)) / 0.6745 / np.sqrt(20.0))


def savgol_window(y: np.ndarray, polyorder: int = 3) -> int:
    """The longest Savitzky–Golay window whose smoothing residual stays at the noise level
    (the discrepancy principle): longer windows average more noise, but once the residual
    exceeds the noise they start to cut the signal itself."""
    y = np.asarray(y, float)
    sigma = noise_level(y)
    n = len(y)
    best = polyorder + 2 | 1
    length = best
    while length < n // 4:
        resid = y - savgol_filter(y, length, polyorder, mode="interp")
        if np.sqrt(np.mean(resid**2)) > 1.02 * sigma:
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


def estimate_velocity(y: np.ndarray, t: np.ndarray, method: str, gains: ObserverGains | None = None):
    """Velocity of the measured position ``y`` by the named ``method``."""
    dt = float(t[1] - t[0])
    if method == "observer":
        return observer(y, dt, gains or ObserverGains())
    if method == "savgol":
        return savgol(y, dt)
    if method == "spline":
        return spline(y, t)
    raise CvxidError(
        f"unknown velocity estimator '{method}'; use one of {', '.join(ESTIMATORS)} "
        "or the name of a measured velocity column"
    )


def model_smoother(y, t, force, system, sigma: float | None = None, q: float | None = None,
                   delayed: np.ndarray | None = None, passes: int = 2):
    r"""Velocity from a Kalman (Rauch–Tung–Striebel) smoother built on a model.

    The state :math:`s = (x, \dot x)` follows the model's own dynamics (RK4 over one
    sample), linearised around a reference trajectory (first the Savitzky–Golay estimate,
    then the previous pass); the model's error enters as white acceleration noise of
    intensity ``q`` (chosen by the innovations' likelihood when not given); the measurement
    is :math:`x` with noise ``sigma`` (estimated when not given).  Where the model predicts
    the motion, the velocity keeps its full bandwidth instead of being low-passed.

    ``delayed`` is the delayed signal of the feedback on the sample grid (an exogenous
    input to the smoother; by default the smoothed position shifted by ``system.tau``).
    Returns ``(x_smoothed, v_smoothed)``.
    """
    y = np.asarray(y, float)
    t = np.asarray(t, float)
    dt = float(t[1] - t[0])
    sigma = noise_level(y) if sigma is None else float(sigma)
    x_ref, v_ref = savgol_filter(y, savgol_window(y), 3, mode="interp"), savgol(y, dt)
    f = np.asarray(force, float)
    if delayed is None:
        delayed = _shifted(x_ref, system, dt)
    for _ in range(int(passes)):
        A, c = _linearise(system, x_ref, v_ref, f, delayed, dt)
        if q is None:
            grid = np.logspace(-6, 4, 11)  # (acceleration units)^2 s
            q_best = max(grid, key=lambda qq: _kalman(y, A, c, sigma, qq, dt, x_ref[0], v_ref[0])[2])
        else:
            q_best = q
        x_ref, v_ref, _ = _kalman(y, A, c, sigma, q_best, dt, x_ref[0], v_ref[0], smooth=True)
    return x_ref, v_ref


def _shifted(x, system, dt):
    lag = float(np.ravel(system.tau)[0]) / dt if system.gain else 0.0
    if not system.gain:
        return np.zeros_like(x)
    idx = np.arange(len(x)) - lag
    out = np.interp(idx, np.arange(len(x)), x)
    out[idx < 0] = 0.0 if system.history == "zero" else x[0]
    return out


def _accel(system, x, v, f, xd):
    coefs = np.atleast_2d(system.coefficients)[0]
    coord = system.coordinate
    states = {coord: x, coord + "'": v}
    rhs = f + system.gain * xd
    for term, c in zip(system.terms, coefs):
        rhs = rhs - c * term.evaluate(states)
    return rhs / float(np.ravel(system.mass)[0])


def _step(system, x, v, f0, f1, d0, d1, dt):
    """One RK4 step of every sample at once (inputs linear between samples)."""
    fm, dm = 0.5 * (f0 + f1), 0.5 * (d0 + d1)
    a1 = _accel(system, x, v, f0, d0)
    a2 = _accel(system, x + 0.5 * dt * v, v + 0.5 * dt * a1, fm, dm)
    v2 = v + 0.5 * dt * a1
    a3 = _accel(system, x + 0.5 * dt * v2, v + 0.5 * dt * a2, fm, dm)
    v3 = v + 0.5 * dt * a2
    a4 = _accel(system, x + dt * v3, v + dt * a3, f1, d1)
    v4 = v + dt * a3
    return x + dt / 6 * (v + 2 * v2 + 2 * v3 + v4), v + dt / 6 * (a1 + 2 * a2 + 2 * a3 + a4)


def _linearise(system, x, v, f, xd, dt):
    """Transition matrices A_k and offsets c_k of s_{k+1} = A_k s_k + c_k around (x, v)."""
    args = (f[:-1], f[1:], xd[:-1], xd[1:], dt)
    x0, v0 = x[:-1], v[:-1]
    base = np.array(_step(system, x0, v0, *args))
    hx = 1e-6 * max(1.0, np.abs(x).max())
    hv = 1e-6 * max(1.0, np.abs(v).max())
    dx = (np.array(_step(system, x0 + hx, v0, *args)) - base) / hx
    dv = (np.array(_step(system, x0, v0 + hv, *args)) - base) / hv
    A = np.stack([dx.T, dv.T], axis=2)  # (n-1, 2, 2): columns d/dx, d/dv
    c = base.T - np.einsum("kij,kj->ki", A, np.stack([x0, v0], axis=1))
    return A, c


def _kalman(y, A, c, sigma, q, dt, x0, v0, smooth=False):
    """Kalman filter (log-likelihood) and optional RTS smoother; 2x2 algebra unrolled in
    plain floats (numpy's per-call cost would dominate on 2x2 matrices)."""
    n = len(y)
    q11, q12, q22 = q * dt**3 / 3, q * dt**2 / 2, q * dt
    R = sigma**2
    a11, a12, a21, a22 = (A[:, 0, 0].tolist(), A[:, 0, 1].tolist(), A[:, 1, 0].tolist(), A[:, 1, 1].tolist())
    c1, c2 = c[:, 0].tolist(), c[:, 1].tolist()
    ys = np.asarray(y, float).tolist()
    m1, m2 = float(x0), float(v0)
    p11, p12, p22 = R, 0.0, (10 * sigma / dt) ** 2
    filt = [None] * n
    pred = [None] * n
    loglik = 0.0
    log2pi = np.log(2 * np.pi)
    for k in range(n):
        if k:
            j = k - 1
            b11, b12, b21, b22 = a11[j], a12[j], a21[j], a22[j]
            m1, m2 = b11 * m1 + b12 * m2 + c1[j], b21 * m1 + b22 * m2 + c2[j]
            # P = A P A^T + Q
            t11, t12 = b11 * p11 + b12 * p12, b11 * p12 + b12 * p22
            t21, t22 = b21 * p11 + b22 * p12, b21 * p12 + b22 * p22
            p11 = t11 * b11 + t12 * b12 + q11
            p12 = t11 * b21 + t12 * b22 + q12
            p22 = t21 * b21 + t22 * b22 + q22
        pred[k] = (m1, m2, p11, p12, p22)
        s = p11 + R
        g1, g2 = p11 / s, p12 / s
        innov = ys[k] - m1
        loglik -= 0.5 * (log2pi + np.log(s) + innov * innov / s)
        m1, m2 = m1 + g1 * innov, m2 + g2 * innov
        p11, p12, p22 = p11 - g1 * p11, p12 - g1 * p12, p22 - g2 * p12
        filt[k] = (m1, m2, p11, p12, p22)
    if not smooth:
        return None, None, loglik
    xs, vs = np.empty(n), np.empty(n)
    s1, s2, s11, s12, s22 = filt[-1]
    xs[-1], vs[-1] = s1, s2
    for k in range(n - 2, -1, -1):
        f1, f2, f11, f12, f22 = filt[k]
        n1, n2, n11, n12, n22 = pred[k + 1]
        b11, b12, b21, b22 = a11[k], a12[k], a21[k], a22[k]
        # G = P_f A^T Pp^-1
        u11, u12 = f11 * b11 + f12 * b12, f11 * b21 + f12 * b22
        u21, u22 = f12 * b11 + f22 * b12, f12 * b21 + f22 * b22
        det = n11 * n22 - n12 * n12
        i11, i12, i22 = n22 / det, -n12 / det, n11 / det
        G11, G12 = u11 * i11 + u12 * i12, u11 * i12 + u12 * i22
        G21, G22 = u21 * i11 + u22 * i12, u21 * i12 + u22 * i22
        d1, d2 = s1 - n1, s2 - n2
        s1, s2 = f1 + G11 * d1 + G12 * d2, f2 + G21 * d1 + G22 * d2
        xs[k], vs[k] = s1, s2
    return xs, vs, loglik
