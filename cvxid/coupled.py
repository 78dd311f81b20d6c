r"""Simulation of coupled second-order systems: several coordinates, one shared delay.

.. math::

    m_i\,\ddot q_i + \sum_j c_{ij}\, g_{ij}(q, \dot q) = \beta_i\, u(t) + b_i\, q_d(t-\tau),
    \qquad i = 1..N,

where every equation has its own coordinate :math:`q_i` (its second derivative is the
equation's inertia), the terms may read every coordinate, :math:`u` is one shared input and
:math:`q_d` the coordinate fed back with the delay :math:`\tau`.

:func:`simulate_coupled` integrates it with compiled RK4 and a Hermite history buffer
(the delayed coordinate's position and velocity); :func:`integrate_coupled` runs a batch of
parameter variants at once (what a finite-difference Jacobian needs).  Identification is in
:mod:`cvxid.identify.joint`, the paper's rig in :mod:`cvxid.tools.flexible_joint`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit

from cvxid.errors import CvxidError
from cvxid.model.terms import AbsProduct, Constant, Monomial, Sign, Term
from cvxid.simulate import SimulationDiverged, half_steps, hermite_stages


@dataclass(frozen=True)
class Equation:
    """One equation of a coupled system with numeric coefficients."""

    coordinate: str
    mass: float
    terms: tuple[Term, ...]
    coefficients: tuple[float, ...]
    input_gain: float = 1.0
    delay_gain: float = 0.0


@dataclass(frozen=True)
class CoupledSystem:
    equations: tuple[Equation, ...]
    delayed: str
    tau: float
    history: str = "zero"

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Coefficients ``(T, 1)``, inertias and delay gains ``(C, 1)``: a batch of one for
        :func:`integrate_coupled`."""
        return (np.concatenate([eq.coefficients for eq in self.equations])[:, None],
                np.array([[eq.mass] for eq in self.equations]), np.array([[eq.delay_gain] for eq in self.equations]))


def simulate_coupled(system: CoupledSystem, time: np.ndarray, force: Callable[[np.ndarray], np.ndarray] | np.ndarray,
                     x0: dict, v0: dict) -> tuple[dict, dict]:
    """Positions and velocities of every coordinate at the sample ``time`` (compiled RK4,
    one step per sample; the delay must be at least one step).  ``force`` is the shared
    input (a function of time or samples on ``time``), scaled by each equation's
    ``input_gain``."""
    t = np.asarray(time, float)
    coords = [eq.coordinate for eq in system.equations]
    if system.delayed not in coords:
        raise CvxidError(f"the delayed coordinate {system.delayed!r} is not one of {coords}")
    f = half_steps(force, t, float(t[1] - t[0]), t.size - 1)
    forces = f[:, None] * np.array([eq.input_gain for eq in system.equations])[None, :]
    X, V = integrate_coupled(system, t, forces, *system.arrays(), np.array([system.tau]),
                             np.array([[x0[c]] for c in coords]), np.array([[v0[c]] for c in coords]))
    return {c: X[:, j, 0] for j, c in enumerate(coords)}, {c: V[:, j, 0] for j, c in enumerate(coords)}


def integrate_coupled(system: CoupledSystem, t: np.ndarray, forces: np.ndarray, coefs: np.ndarray, mass: np.ndarray,
                      delay_gain: np.ndarray, tau: np.ndarray, x0: np.ndarray, v0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A batch of ``B`` variants of ``system``'s structure at once: ``forces`` ``(2n-1, C)``
    at the RK4 nodes and midpoints, ``coefs`` ``(T, B)`` (every equation's terms in
    order), ``mass`` and ``delay_gain`` ``(C, B)``, ``tau`` ``(B,)``, initial states
    ``(C, B)``.  Returns positions and velocities ``(n, C, B)``."""
    h = float(t[1] - t[0])
    if np.any(tau < h):
        raise CvxidError(f"the delay {np.min(tau):g} s is shorter than the step {h:g} s")
    if np.any(mass <= 0):
        raise SimulationDiverged(f"an inertia is {np.min(mass):g} (not positive): the model cannot be simulated")
    coords = [eq.coordinate for eq in system.equations]
    d = coords.index(system.delayed)
    offs, ws = hermite_stages(tau, h)
    fill = np.zeros(tau.size) if system.history == "zero" else np.asarray(x0[d], float).copy()
    X, V, failed = _coupled_kernel(np.ascontiguousarray(forces, float), np.ascontiguousarray(mass, float),
                                   np.ascontiguousarray(coefs, float), *_codes(system), np.ascontiguousarray(delay_gain, float),
                                   d, offs, ws, fill, np.ascontiguousarray(x0, float), np.ascontiguousarray(v0, float),
                                   h, t.size - 1)
    if failed >= 0:
        raise SimulationDiverged(f"the coupled simulation diverged at t = {t[0] + failed * h:.4g} s")
    return X, V


def _codes(system: CoupledSystem):
    """Every term of every equation as (equation, kind, powers of positions, powers of
    velocities, coordinate, smoothing) for the compiled kernel."""
    coords = [eq.coordinate for eq in system.equations]
    symbols = {c: j for j, c in enumerate(coords)}
    rows = []
    for e, eq in enumerate(system.equations):
        for term in eq.terms:
            px, pv = np.zeros(len(coords), np.int64), np.zeros(len(coords), np.int64)
            if isinstance(term, Monomial) and all(s.rstrip("'") in symbols for s in term.factors):
                for s, p in term.factors.items():
                    (pv if s.endswith("'") else px)[symbols[s.rstrip("'")]] = p
                rows.append((e, 0, px, pv, 0, 0.0))
            elif isinstance(term, Constant):
                rows.append((e, 0, px, pv, 0, 0.0))
            elif isinstance(term, Sign) and term.coordinate in symbols:
                rows.append((e, 3 if term.smoothing else 1, px, pv, symbols[term.coordinate], term.smoothing))
            elif isinstance(term, AbsProduct) and term.coordinate in symbols:
                rows.append((e, 2, px, pv, symbols[term.coordinate], 0.0))
            else:
                raise CvxidError(f"the coupled simulator cannot evaluate the term {term.name!r}: it takes "
                                 "monomials, sign(q'), q'|q'| and constants of the system's coordinates")
    if not rows:
        return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, len(coords)), np.int64),
                np.zeros((0, len(coords)), np.int64), np.zeros(0, np.int64), np.zeros(0))
    eqs, kinds, px, pv, tc, scale = zip(*rows)
    return (np.array(eqs, np.int64), np.array(kinds, np.int64), np.array(px), np.array(pv),
            np.array(tc, np.int64), np.array(scale, float))


@njit(cache=True)
def _coupled_accel(b, s, x, v, k, ci, F, mass, coefs, eqs, kinds, px, pv, tc, scale, dgain, d, offs, ws, fill,
                   X, V, steps, out):
    C = x.size
    i = k + offs[ci, b]
    w0 = ws[ci, 0, b]
    if i < 0 or (i == 0 and w0 == 1.0 and ci == 2):
        qd = fill[b]
    else:
        j = min(i, steps - 1)
        qd = (w0 * X[j, d, b] + ws[ci, 1, b] * V[j, d, b] + ws[ci, 2, b] * X[j + 1, d, b]
              + ws[ci, 3, b] * V[j + 1, d, b])
    for e in range(C):
        out[e] = F[s, e] + dgain[e, b] * qd
    for m in range(eqs.size):
        kind = kinds[m]
        if kind == 0:
            val = 1.0
            for c in range(C):
                val *= x[c] ** px[m, c] * v[c] ** pv[m, c]
        elif kind == 1:
            w = v[tc[m]]
            val = 1.0 if w > 0 else (-1.0 if w < 0 else 0.0)
        elif kind == 2:
            val = v[tc[m]] * abs(v[tc[m]])
        else:
            val = np.tanh(v[tc[m]] / scale[m])
        out[eqs[m]] -= coefs[m, b] * val
    for e in range(C):
        out[e] /= mass[e, b]


@njit(cache=True)
def _coupled_kernel(F, mass, coefs, eqs, kinds, px, pv, tc, scale, dgain, d, offs, ws, fill, x0, v0, h, steps):
    """RK4 with a Hermite history of the delayed coordinate, one system of the batch at a
    time (the same scheme as :func:`cvxid.simulate.simulate`, for several coordinates)."""
    C, B = x0.shape
    X = np.zeros((steps + 1, C, B))
    V = np.zeros((steps + 1, C, B))
    a1, a2, a3, a4 = np.zeros(C), np.zeros(C), np.zeros(C), np.zeros(C)
    failed = -1
    for b in range(B):
        x, v = x0[:, b].copy(), v0[:, b].copy()
        X[0, :, b], V[0, :, b] = x, v
        for k in range(steps):
            _coupled_accel(b, 2 * k, x, v, k, 0, F, mass, coefs, eqs, kinds, px, pv, tc, scale, dgain, d, offs, ws,
                           fill, X, V, steps, a1)
            x2, v2 = x + 0.5 * h * v, v + 0.5 * h * a1
            _coupled_accel(b, 2 * k + 1, x2, v2, k, 1, F, mass, coefs, eqs, kinds, px, pv, tc, scale, dgain, d, offs,
                           ws, fill, X, V, steps, a2)
            x3, v3 = x + 0.5 * h * v2, v + 0.5 * h * a2
            _coupled_accel(b, 2 * k + 1, x3, v3, k, 1, F, mass, coefs, eqs, kinds, px, pv, tc, scale, dgain, d, offs,
                           ws, fill, X, V, steps, a3)
            x4, v4 = x + h * v3, v + h * a3
            _coupled_accel(b, 2 * k + 2, x4, v4, k, 2, F, mass, coefs, eqs, kinds, px, pv, tc, scale, dgain, d, offs,
                           ws, fill, X, V, steps, a4)
            x = x + h / 6 * (v + 2 * v2 + 2 * v3 + v4)
            v = v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
            X[k + 1, :, b], V[k + 1, :, b] = x, v
            if not (np.abs(x).max() < 1e8 and np.abs(v).max() < 1e8):
                if failed < 0 or k + 1 < failed:
                    failed = k + 1
                break
    return X, V, failed


