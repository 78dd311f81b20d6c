r"""The initial state of a compared record, estimated as MATLAB's ``compare`` does.

A free-run comparison needs the state :math:`(x_0, \dot x_0)` of every coordinate where the
simulation starts.  Read off the record (a Savitzky–Golay fit of its first samples) the
velocity carries the noise of a derivative, and a wrong start shows as a transient that
hides an accurate model.  Estimated, the start is the state that best explains the whole
compared record under the model:

.. math::

    \hat s_0 = \arg\min_{s_0} \sum_c
    \frac{\|y_c - \hat y_c(s_0)\|^2}{\|y_c - \bar y_c\|^2},

solved by :func:`scipy.optimize.least_squares` from the record's own state.  The estimate
never changes the model, only where its simulation starts; a comparison reports which
start it used and the fit from the record's own start beside it.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.optimize import least_squares

from cvxid.errors import CvxidError
from cvxid.simulate import SimulationDiverged

INITIAL_STATES = ("estimated", "record")
"""How a comparison starts its free run: the state estimated by least squares over the
compared record, or the record's own (smoothed) first state."""

MAX_EVALUATIONS = 60
"""Simulations the least-squares search may spend (a handful of Gauss–Newton steps)."""

TOLERANCE = 1e-6
"""The search stops when a step changes the squared error, or the start, by less than this
share (a fit read to 0.01 % needs 1e-4; the solver's default 1e-8 spent twice the
simulations for digits no comparison reads)."""

STEP = 1e-6
"""The relative step of the forward differences in the start, of at least this share of
the coordinate's measured spread (a floor of 1 in the data's units was a step as large as
the state itself in data written in micrometres)."""

DIVERGED_RESIDUAL = 1e3
"""The normalised residual of a trial start whose simulation diverges (a wall, not a NaN)."""

State = dict[str, tuple[float, float]]


def check_initial_state(value: str) -> str:
    """``value`` if it names a way to start a comparison, else a clear error."""
    if value not in INITIAL_STATES:
        raise CvxidError(f"initial must be one of {', '.join(INITIAL_STATES)}, got {value!r}")
    return value


def free_run(simulate: Callable[[State], dict[str, np.ndarray]], measured: dict[str, np.ndarray], own: State,
             initial: str) -> tuple[State, dict[str, np.ndarray], dict[str, np.ndarray] | None]:
    """The free run a comparison shows: from the record's ``own`` start (``initial =
    "record"``), or from the start :func:`estimate_initial_state` finds, with the run from
    the record's own start kept beside it.  Returns the start, its run and the own-start run
    (None unless estimated); raises :class:`~cvxid.simulate.SimulationDiverged`."""
    check_initial_state(initial)
    sim = simulate(own)
    if initial == "record":
        return own, sim, None
    state = estimate_initial_state(simulate, measured, own)
    return state, simulate(state), sim


def estimate_initial_state(simulate: Callable[[State], dict[str, np.ndarray]],
                           measured: dict[str, np.ndarray], guess: State) -> State:
    """The start (coordinate → (position, velocity)) whose free run best fits ``measured``.

    Parameters
    ----------
    simulate
        Maps a start to the simulated outputs on the samples of ``measured`` (NaN where the
        simulation does not cover them), and a batch of starts (arrays ``(B,)``) to their
        runs ``(n, B)``; raises :class:`~cvxid.simulate.SimulationDiverged`.
    measured
        The measured output of every coordinate on the compared samples.
    guess
        The record's own start, where the search begins; returned unchanged when the search
        cannot improve on it.
    """
    coords = list(guess)
    scale = {c: float(np.nanstd(measured[c])) or 1.0 for c in coords}
    size = sum(len(measured[c]) for c in coords)

    def unpack(p: np.ndarray) -> State:
        return {c: (p[2 * i], p[2 * i + 1]) for i, c in enumerate(coords)}

    def residuals(P: np.ndarray) -> np.ndarray:
        """The residual of each start, a column of ``P`` (one batch of simulations)."""
        try:
            sim = simulate(unpack(P))
        except SimulationDiverged:
            return np.full((size, P.shape[1]), DIVERGED_RESIDUAL)
        parts = [np.nan_to_num((sim[c] - measured[c][:, None]) / scale[c], nan=0.0) for c in coords]
        return np.concatenate(parts) / np.sqrt(size)

    def residual(p: np.ndarray) -> np.ndarray:
        return residuals(p[:, None])[:, 0]

    def jacobian(p: np.ndarray) -> np.ndarray:
        """Forward differences, every column in one batch (a batch that diverges: one at a time)."""
        steps = STEP * np.maximum(floors, np.abs(p))
        P = p[:, None] + np.column_stack([np.zeros(p.size), np.diag(steps)])
        R = residuals(P)
        if np.all(R[:, 1:] == DIVERGED_RESIDUAL):
            R = np.column_stack([residual(q) for q in P.T])
        return (R[:, 1:] - R[:, :1]) / steps

    floors = np.repeat([scale[c] for c in coords], 2)  # (a position's spread, and its velocity's floor too)
    p0 = np.array([v for c in coords for v in guess[c]], dtype=float)
    start = residual(p0)
    if np.all(start == DIVERGED_RESIDUAL):
        return guess
    # searched in units of each coordinate's spread: scipy's gradient test is not unit-free (a record in
    # micrometres, 1e7 times larger, stopped at the guess with a gradient of 7e-10, below its 1e-8)
    solution = least_squares(lambda q: residual(q * floors), p0 / floors, jac=lambda q: jacobian(q * floors) * floors,
                             x_scale="jac", ftol=TOLERANCE, xtol=TOLERANCE, max_nfev=MAX_EVALUATIONS)
    if solution.cost >= 0.5 * float(start @ start):
        return guess
    return {c: (float(x), float(v)) for c, (x, v) in unpack(solution.x * floors).items()}
