r"""The identification as a cvxpy problem.

.. math::

    \min_{\tilde c}\; \frac{1}{n}\,\|R\,\tilde c - r\|_2^2
        + \lambda \sum_i w_i\,|\tilde c_i|
    \quad\text{s.t.}\quad \tilde c_j \ge 0,\ j \in \mathcal{N},

on the reduced, scaled regression (see :mod:`cvxid.regression.regression`): :math:`\lambda` is a
``cp.Parameter``, so the problem is canonicalised once and re-solved for each value
(Clarabel is handed the canonical data directly: :math:`\lambda` moves only the linear
cost, :class:`CanonicalClarabel`);
:math:`w_i = 0` on inertia and delay columns; :math:`\mathcal{N}` are the named sign
constraints.  Coefficients leave in physical units.  Scaling makes :math:`\lambda`
dimensionless: the target has unit mean square, so :math:`\lambda \gtrsim 2` zeroes every
penalised column.
"""

from __future__ import annotations

import functools
import time
import warnings
from dataclasses import dataclass, field, replace

import cvxpy as cp
import numpy as np
import scipy.sparse as sp
from scipy.linalg import solve_triangular
from scipy.optimize import lsq_linear

from cvxid.errors import CvxidError, CvxidWarning, SolverFailure
from cvxid.regression.regression import Reduced, Regression

SOLVERS = ("CLARABEL", "OSQP", "SCS")
SOLVER_SETTINGS = {
    # tight tolerances: the defaults misreport badly scaled problems (notes/solvers.md)
    "CLARABEL": dict(tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10, tol_ktratio=1e-8),
    "OSQP": dict(eps_abs=1e-9, eps_rel=1e-9, max_iter=200_000, polishing=True),
    "SCS": dict(eps_abs=1e-9, eps_rel=1e-9, max_iters=200_000),
}
ADAPTIVE_GAMMA = 1.0
"""The adaptive lasso's exponent: weights ``(max|c| / |c_i|)^gamma`` (:meth:`Problem.adaptive`)."""
ADAPTIVE_RIDGE = 1e-8
"""The ridge of the adaptive weights' least squares, per row (columns have unit mean square:
negligible unless columns are collinear)."""
ADAPTIVE_MAX_WEIGHT = 1e6
"""The largest ratio ``max|c| / |c_i|`` used: a column a million times weaker than the
strongest is out at every lambda of the default grid anyway, and larger weights leave the
solver a badly scaled problem (an exact zero would be an infinite weight)."""
SUPPORT_TOL = 1e-7
"""A scaled coefficient smaller than this (target has unit RMS) counts as zero."""


@dataclass(frozen=True)
class Fit:
    """One solution of the problem."""

    lam: float
    coefficients: np.ndarray  # physical units
    scaled: np.ndarray
    support: np.ndarray  # boolean mask
    objective: float
    train_mse: float  # mean squared equation error, physical units
    status: str
    solver: str
    seconds: float
    names: tuple[str, ...] = field(default=())

    def __repr__(self) -> str:
        names = self.names or tuple(f"c{i}" for i in range(len(self.coefficients)))
        terms = ", ".join(f"{n} = {c:.4g}" for n, c, k in zip(names, self.coefficients, self.support) if k)
        return (f"Fit at lambda = {self.lam:.3g} ({self.solver}, {self.status}): {int(np.sum(self.support))} of "
                f"{len(names)} columns, training MSE {self.train_mse:.4g}: {terms or 'none'}")


class Problem:
    """A weighted-L1, sign-constrained least-squares problem over named coefficients.

    Build it with :meth:`from_regression` (cvxid's own regressions) or :meth:`from_arrays`
    (any user's regressors).
    """

    def __init__(
        self,
        reduced: Reduced,
        names,
        penalties,
        nonnegative=(),
        solver: str = "CLARABEL",
        ties=(),
    ):
        self.reduced = reduced
        self.names = tuple(names)
        self.penalties = np.asarray(penalties, dtype=float)
        k = len(self.names)
        if self.penalties.shape != (k,) or np.any(self.penalties < 0):
            raise CvxidError(f"weights must be {k} non-negative numbers, one per column")
        if isinstance(nonnegative, str):  # (read letter by letter it named "unknown column(s) ', '")
            raise CvxidError(f"nonnegative takes a list of column names: [{nonnegative!r}], not {nonnegative!r}")
        unknown = [n for n in nonnegative if n not in self.names]
        if unknown:
            raise CvxidError(
                f"nonnegative names unknown column(s) {', '.join(unknown)}; columns: {', '.join(self.names)}"
            )
        self.nonnegative = tuple(nonnegative)
        self.ties = tuple((str(a), str(b), float(f)) for a, b, f in ties)
        for a, b, f in self.ties:
            if a not in self.names or b not in self.names or a == b or not np.isfinite(f):
                raise CvxidError(
                    f"tie {a} = {f:g} * {b}: both must be distinct columns ({', '.join(self.names)}) "
                    "and the factor finite"
                )
        self.solver = str(solver).upper()
        if self.solver not in SOLVERS:
            raise CvxidError(f"unknown solver '{solver}'; use one of {', '.join(SOLVERS)}")
        if self.solver != "CLARABEL":
            warnings.warn(
                f"{self.solver} (a first-order solver) is not accurate on badly scaled regressions like these "
                "(docs/spec.md, [fit] solver); results are checked, but prefer CLARABEL",
                CvxidWarning,
                stacklevel=2,
            )
        # Columns that are neither penalised nor constrained are projected out before the
        # L1 solve (notes/solvers.md): a QR of R with those columns first splits
        # ||R c - r||^2 into a block they can always zero and a block in the others only.
        tied = {n for a, b, _ in self.ties for n in (a, b)}
        free = [i for i in range(k) if self.penalties[i] == 0 and self.names[i] not in set(self.nonnegative) | tied]
        self._free = np.array(free, dtype=int)
        self._rest = np.array([i for i in range(k) if i not in free], dtype=int)
        Q, Rp = np.linalg.qr(reduced.R[:, np.r_[self._free, self._rest]])
        rp = Q.T @ reduced.r
        u = len(free)
        self._back = (Rp[:u, :u], Rp[:u, u:], rp[:u])  # c_free = R_uu^-1 (r_u - R_us c_rest)
        self.c = cp.Variable(len(self._rest), name="c")
        self.lam = cp.Parameter(nonneg=True, name="lambda", value=0.0)
        self.objective = cp.sum_squares(Rp[u:, u:] @ self.c - rp[u:]) / reduced.rows + self.lam * cp.norm1(
            cp.multiply(self.penalties[self._rest], self.c)
        )
        index = {self.names[i]: j for j, i in enumerate(self._rest)}
        self.constraints = {f"c[{n}] >= 0": self.c[index[n]] >= 0 for n in self.nonnegative}
        for a, b, f in self.ties:  # physical c_a = f c_b, in scaled units
            self.constraints[f"c[{a}] = {f:g} c[{b}]"] = self.c[index[a]] == _tie_factor(self.reduced, self.names, a, b, f) * self.c[index[b]]
        self.cvxpy = cp.Problem(cp.Minimize(self.objective), list(self.constraints.values()))
        self.regression: Regression | None = None  # the rows behind the factor, when known
        self._canonical: CanonicalClarabel | bool | None = None  # at the first Clarabel solve (False: cvxpy's)

    def _full(self, rest: np.ndarray) -> np.ndarray:
        """All scaled coefficients from the solved ones (the projected-out ones recovered)."""
        out = np.zeros(self.k)
        out[self._rest] = rest
        if self._free.size:
            Ruu, Rus, ru = self._back
            out[self._free] = solve_triangular(Ruu, ru - Rus @ rest)
        return out

    # ------------------------------------------------------------------ builders
    @property
    def held_by_ties(self) -> np.ndarray:
        """The columns a chain of ties binds to an unpenalised column: whatever lambda is,
        the tie keeps them where that column is (their own penalty cannot remove them)."""
        held = {n for n, w in zip(self.names, self.penalties) if w == 0}
        grown = True
        while grown:
            grown = False
            for a, b, _ in self.ties:
                if (a in held) != (b in held):
                    held |= {a, b}
                    grown = True
        return np.array([n in held and w > 0 for n, w in zip(self.names, self.penalties)])

    @classmethod
    def from_regression(cls, regression: Regression, nonnegative=(), solver="CLARABEL", row_weights=None, ties=()):
        problem = cls(regression.reduce(row_weights), regression.names, regression.penalties, nonnegative, solver,
                      ties)
        problem.regression = regression
        return problem

    @classmethod
    def from_arrays(cls, P, p, names, weights=None, nonnegative=(), solver="CLARABEL", ties=()):
        """A problem from a user's own regressors ``P`` (n × k) and target ``p`` (n)."""
        P = np.asarray(P, dtype=float)
        p = np.asarray(p, dtype=float).ravel()
        if P.ndim != 2 or P.shape[0] != p.size:
            raise CvxidError(f"P must be (n, k) with n = len(p) = {p.size}; got shape {P.shape}")
        if not (np.isfinite(P).all() and np.isfinite(p).all()):
            raise CvxidError("P and p must be finite (no NaN/inf)")
        names = list(names)
        if len(names) != P.shape[1] or len(set(names)) != len(names):
            raise CvxidError(f"names must be {P.shape[1]} distinct strings, one per column of P")
        weights = np.ones(P.shape[1]) if weights is None else np.asarray(weights, dtype=float)
        regression = Regression(P, p, tuple(names), tuple("library" for _ in names), weights)
        return cls.from_regression(regression, nonnegative, solver, ties=ties)

    # ------------------------------------------------------------------ solving
    @property
    def k(self) -> int:
        return len(self.names)

    def _attempt(self, solver: str, settings: dict) -> str | None:
        """One solve by ``solver``; the solver's error message, or None."""
        try:
            with warnings.catch_warnings():
                # cvxpy's own "may be inaccurate" warning: the status is checked by solve()
                warnings.filterwarnings("ignore", message="Solution may be inaccurate")
                if solver == "CLARABEL" and self._canonical is None:
                    self._canonical = CanonicalClarabel.of(self.cvxpy, self.lam)
                if solver == "CLARABEL" and self._canonical:
                    self._canonical.solve(float(self.lam.value), settings)
                else:
                    self.cvxpy.solve(solver=solver, warm_start=False, **settings)
        except cp.error.SolverError as exc:
            return str(exc)
        return None

    def _answer(self, solver: str) -> str | None:
        """Solve by ``solver`` (Clarabel retried once with its defaults); None when it
        answered optimally, else what went wrong."""
        error = self._attempt(solver, SOLVER_SETTINGS[solver])
        if solver == "CLARABEL" and (error is not None or self.cvxpy.status == cp.OPTIMAL_INACCURATE):
            # the tight tolerances occasionally stall on badly scaled data: retry once with
            # the solver's defaults and keep the retry if it is sound (notes/solvers.md)
            error = self._attempt(solver, {})
        if error is not None:
            return error
        status = self.cvxpy.status
        if status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE):
            # signs and ties are homogeneous (all zero satisfies them): a numerical failure
            return (f"it reported the constraints ({', '.join(self.constraints)}) infeasible, though all zero "
                    "satisfies them")
        if status == cp.OPTIMAL_INACCURATE and self.c.value is not None:
            return "it reported an inaccurate solution"
        if status != cp.OPTIMAL or self.c.value is None:
            return f"it stopped with status '{status}'"
        return None

    def _finish(self, lam, scaled, status, seconds, objective=None, solver: str | None = None) -> Fit:
        red = self.reduced
        scaled = np.asarray(scaled, dtype=float)
        resid = red.R @ scaled - red.r
        train = (resid @ resid + red.rho2) / red.rows
        if objective is None:
            objective = train + lam * float(self.penalties @ np.abs(scaled))
        return Fit(
            lam=float(lam),
            coefficients=red.to_physical(scaled),
            scaled=scaled,
            support=np.abs(scaled) > SUPPORT_TOL,
            objective=float(objective),
            train_mse=float(train * red.target_scale**2),
            status=status,
            solver=solver or self.solver,
            seconds=seconds,
            names=self.names,
        )

    def solve(self, lam: float) -> Fit:
        """Solve at one value of :math:`\\lambda` (the problem is not rebuilt)."""
        lam = float(lam)
        if not np.isfinite(lam) or lam < 0:
            raise CvxidError(f"lambda must be a finite number >= 0, got {lam}")
        if not self._rest.size:  # nothing penalised or constrained: the least squares, no solver
            return self._finish(lam, self._full(np.zeros(0)), "optimal", 0.0)
        self.lam.value = lam
        start = time.perf_counter()
        failures, inaccurate = [], None
        for solver in fallbacks(self.solver):
            failure = self._answer(solver)
            if failure is None:
                status, value = cp.OPTIMAL, self.c.value
                break
            if inaccurate is None and self.cvxpy.status == cp.OPTIMAL_INACCURATE and self.c.value is not None:
                inaccurate = (solver, self.c.value.copy())
            failures.append(f"{solver}: {failure}")
        else:
            if inaccurate is None:
                raise SolverFailure(
                    f"no solver answered at lambda = {lam:.3g} ({'; '.join(failures)}); no solution is reported. "
                    "Try a smaller library, a narrower lambda range, or rescale the data"
                )
            (solver, value), status = inaccurate, cp.OPTIMAL_INACCURATE
        seconds = time.perf_counter() - start
        if status == cp.OPTIMAL_INACCURATE:
            warnings.warn(f"only an inaccurate solution at lambda = {lam:.3g} ({'; '.join(failures)}): {solver}'s is "
                          "reported", CvxidWarning, stacklevel=2)
        elif failures:
            warnings.warn(f"solver {'; '.join(failures)} at lambda = {lam:.3g}; {solver} answered instead",
                          CvxidWarning, stacklevel=2)
        return self._polish(self._finish(lam, self._full(value), status, seconds, solver=solver))

    def _polish(self, fit: Fit) -> Fit:
        """Polish on the support: with the support and signs fixed the problem is a least
        squares with a linear term, solved exactly; kept only if it keeps the signs and the
        constraints and lowers the objective (interior-point solutions stop short of it)."""
        S = np.flatnonzero(fit.support)
        if S.size == 0 or self.ties:  # (the closed form below does not keep ties)
            return fit
        R, red = self.reduced.R[:, S], self.reduced
        signs = np.sign(fit.scaled[S])
        rhs = R.T @ red.r - 0.5 * fit.lam * red.rows * self.penalties[S] * signs
        try:
            cS = np.linalg.solve(R.T @ R, rhs)
        except np.linalg.LinAlgError:
            return fit
        penalised = self.penalties[S] > 0
        if np.any(np.sign(cS[penalised]) != signs[penalised]):
            return fit
        scaled = np.zeros(self.k)
        scaled[S] = cS
        if any(scaled[self.names.index(n)] < 0 for n in self.nonnegative):
            return fit
        polished = self._finish(fit.lam, scaled, fit.status, fit.seconds, solver=fit.solver)
        return polished if polished.objective < fit.objective else fit

    def adaptive(self, gamma: float = ADAPTIVE_GAMMA) -> "Problem":
        r"""The adaptive lasso's problem (Zou, 2006): the same factor with every penalised
        column's weight divided by the size of its least-squares coefficient,

        .. math::

            w_i^{\text{adaptive}} = w_i \left(\frac{\max_j |\hat c_j|}{|\hat c_i|}\right)^{\gamma},

        :math:`\hat c` the constrained least squares on every column (scaled units), with a
        ridge of :data:`ADAPTIVE_RIDGE` times the rows so that exactly collinear columns share
        their coefficient instead of trading huge opposite ones; the max over penalised
        columns.  The strongest column keeps its weight, so the top of the
        :math:`\lambda` grid still zeroes every penalised term; weak columns need a small
        :math:`\lambda` to enter.  On collinear libraries the plain lasso's path can miss the
        true support altogether (a correlated wrong term enters first); these weights restore
        it when least squares ranks the columns right (``notes/selection.md``)."""
        penalised = self.penalties > 0
        if not penalised.any():
            return self
        red = self.reduced
        Q, R = np.linalg.qr(np.vstack([red.R, np.sqrt(ADAPTIVE_RIDGE * red.rows) * np.eye(self.k)]))
        ridged = replace(red, R=R, r=Q.T @ np.concatenate([red.r, np.zeros(self.k)]))
        ls = np.abs(constrained_least_squares(ridged, self.names, np.ones(self.k, bool), self.nonnegative, self.ties))
        top = ls[penalised].max()
        if top == 0:
            return self
        weights = np.where(penalised, self.penalties * (top / np.maximum(ls, top / ADAPTIVE_MAX_WEIGHT)) ** gamma, 0.0)
        with warnings.catch_warnings():  # a first-order solver was warned about with this problem
            warnings.simplefilter("ignore", CvxidWarning)
            problem = Problem(self.reduced, self.names, weights, self.nonnegative, self.solver, self.ties)
        problem.regression = self.regression
        return problem

    def refit(self, support, lam: float = 0.0) -> Fit:
        """Least squares on ``support`` (plus every unpenalised column), keeping the sign
        constraints and the ties: the debiased estimate."""
        mask = np.asarray(support, dtype=bool) | (self.penalties == 0)
        start = time.perf_counter()
        scaled = constrained_least_squares(self.reduced, self.names, mask, self.nonnegative, self.ties)
        return self._finish(lam, scaled, "optimal", time.perf_counter() - start)

    def __str__(self) -> str:
        red = self.reduced
        lines = [
            "minimize    (1/n) ||R c - r||^2 + lambda * sum_i w_i |c_i|",
            f"  n = {red.rows:g} rows reduced to a {self.k}x{self.k} triangular factor R; "
            f"{self._free.size} free column(s) projected out, {self._rest.size} in the cvxpy problem",
            f"  lambda = {self.lam.value:g} (cvxpy Parameter), solver {self.solver}",
        ]
        if self.constraints:
            lines.append("subject to  " + ", ".join(self.constraints))
        lines.append(f"  {'column':<14} {'w_i':>4}  {'scale (c = c~ * s_p / s_i)':>26}")
        for n, w, s in zip(self.names, self.penalties, red.column_scale):
            lines.append(f"  {n:<14} {w:>4g}  {red.target_scale / s:>26.4e}")
        return "\n".join(lines)

    __repr__ = __str__


class CanonicalClarabel:
    r"""A cvxpy problem whose parameter :math:`\lambda` enters only the linear cost, solved
    by Clarabel on its canonical data: cvxpy canonicalises it once (at :math:`\lambda` = 0
    and 1: :math:`q(\lambda) = q_0 + \lambda (q_1 - q_0)`, the quadratic cost, the
    constraints and the cones the same), each :math:`\lambda` is a fresh Clarabel solver on
    that data, and cvxpy unpacks the answer into the problem's variables and status.

    A fresh solver and not an update of the last one: updating Clarabel's data in place
    (what cvxpy's ``warm_start=True`` does) returned "optimal_inaccurate" answers 5 % above
    the optimum on these problems, where a fresh solve is exact (measured: ``cvxid bench``,
    order 4).  What is saved is cvxpy's work per solve, most of a small problem's time.
    """

    @classmethod
    def of(cls, problem: cp.Problem, lam: cp.Parameter) -> "CanonicalClarabel | bool":
        r"""The canonical form, or False when :math:`\lambda` moves more than the linear
        cost (then cvxpy solves the problem itself)."""
        try:
            return cls(problem, lam)
        except ValueError:
            return False

    def __init__(self, problem: cp.Problem, lam: cp.Parameter):
        from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import dims_to_solver_cones
        from cvxpy.reductions.solvers.conic_solvers.conic_solver import ConicSolver

        self.problem = problem
        kept = lam.value
        lam.value = 0.0
        data, self.chain, self.inverse = problem.get_problem_data(cp.CLARABEL)
        lam.value = 1.0
        one, _, _ = problem.get_problem_data(cp.CLARABEL)
        lam.value = kept
        self.q0 = np.asarray(data["c"], float)
        self.dq = np.asarray(one["c"], float) - self.q0
        same = all((abs(data[k] - one[k]).max() if data[k].size else 0.0) == 0.0 for k in ("A", "P") if k in data)
        if not same or not np.array_equal(data["b"], one["b"]):
            raise ValueError("lambda moves more than the linear cost of this problem")
        n = self.q0.size
        self.P = sp.triu(data["P"] if "P" in data else sp.csc_array((n, n))).tocsc()
        self.A, self.b = sp.csc_array(data["A"]), np.asarray(data["b"], float)
        self.cones = dims_to_solver_cones(data[ConicSolver.DIMS])

    def solve(self, lam: float, settings: dict) -> None:
        """Solve at ``lam``; the problem's variables and status are set as by ``problem.solve``."""
        import clarabel
        from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import CLARABEL
        from cvxpy.reductions.solvers.solver_inverse_data import SolverInverseData

        options = CLARABEL.parse_solver_opts(False, settings)
        try:
            answer = clarabel.DefaultSolver(self.P, self.q0 + lam * self.dq, self.A, self.b, self.cones,
                                            options).solve()
        except Exception as exc:  # Clarabel's own failure, reported as cvxpy reports it
            raise cp.error.SolverError(str(exc)) from exc
        inverse = self.inverse[:-1] + [SolverInverseData(self.inverse[-1], self.chain.solver, settings)]
        self.problem.unpack_results(answer, self.chain, inverse)


def fallbacks(first: str) -> list[str]:
    """The solvers tried in turn: ``first``, then every other installed one of :data:`SOLVERS`."""
    installed = _installed()
    return [first] + [s for s in SOLVERS if s != first and s in installed]


@functools.lru_cache(maxsize=1)
def _installed() -> frozenset[str]:
    """cvxpy's installed solvers, asked once (cvxpy tries to import every solver it knows)."""
    return frozenset(cp.installed_solvers())


def _tie_factor(reduced: Reduced, names, a: str, b: str, factor: float) -> float:
    r"""The tie :math:`c_a = \rho c_b` in scaled units."""
    scale = reduced.column_scale
    return factor * scale[names.index(a)] / scale[names.index(b)]


def _tied_bounded_least_squares(reduced: Reduced, names, idx, lower, ties) -> np.ndarray | None:
    r"""The tied, sign-constrained least squares by elimination: each tie
    :math:`c_a = \rho c_b` writes a column as a multiple of its group's first one, whose
    column becomes :math:`\sum_i g_i R_{:,i}` (chains of ties compose), and the signs of
    its members bound it; then scipy's bounded least squares.  None when the ties are
    inconsistent (a cycle with another factor) or the signs pin a group at zero: the cvxpy
    problem answers then."""
    where = {names[i]: j for j, i in enumerate(idx)}
    parent = list(range(idx.size))
    share = np.ones(idx.size)  # c_j = share[j] * c_parent[j]

    def root(j):
        g = 1.0
        while parent[j] != j:
            g *= share[j]
            j = parent[j]
        return j, g

    for a, b, f in ties:
        (ra, ga), (rb, gb) = root(where[a]), root(where[b])
        rho = _tie_factor(reduced, names, a, b, f)
        if ra == rb:
            if not np.isclose(ga, rho * gb, rtol=1e-12, atol=0.0):
                return None
            continue
        if ga == 0:
            return None
        parent[ra], share[ra] = rb, rho * gb / ga  # c_ra = c_a / ga = rho gb / ga c_rb
    roots, gains = zip(*(root(j) for j in range(idx.size)))
    groups = sorted(set(roots))
    A = np.zeros((reduced.R.shape[0], len(groups)))
    low, high = np.full(len(groups), -np.inf), np.full(len(groups), np.inf)
    for j, (r, g) in enumerate(zip(roots, gains)):
        k = groups.index(r)
        A[:, k] += g * reduced.R[:, idx[j]]
        if lower[j] == 0 and g != 0:
            low[k], high[k] = (max(low[k], 0.0), high[k]) if g > 0 else (low[k], min(high[k], 0.0))
    if np.any(low >= high):
        return None
    sol = lsq_linear(A, reduced.r, bounds=(low, high), method="bvls")
    if not sol.success:
        return None
    return np.array([g * sol.x[groups.index(r)] for r, g in zip(roots, gains)])


def constrained_least_squares(reduced: Reduced, names, mask, nonnegative=(), ties=()) -> np.ndarray:
    r"""Scaled least-squares coefficients of the reduced regression on the columns in
    ``mask`` (the others zero), ``nonnegative`` columns kept ``>= 0`` (scipy's bounded
    least squares) and ``ties`` ``(a, b, factor)``: :math:`c_a = \rho c_b` (eliminated,
    :func:`_tied_bounded_least_squares`; a small cvxpy problem where they cannot be).  A tie keeps both of its columns or neither."""
    names = tuple(names)
    mask = np.array(mask, dtype=bool)
    spread = True
    while spread:  # a tie keeps both of its columns, along chains of ties in any order
        spread = False
        for a, b, _ in ties:
            ia, ib = names.index(a), names.index(b)
            if mask[ia] != mask[ib]:
                mask[ia] = mask[ib] = spread = True
    ties = [t for t in ties if mask[names.index(t[0])]]  # a tie of two columns off the support holds at zero
    idx = np.flatnonzero(mask)
    lower = np.array([0.0 if names[i] in nonnegative else -np.inf for i in idx])
    scaled = np.zeros(len(names))
    if not ties:
        sol = lsq_linear(reduced.R[:, idx], reduced.r, bounds=(lower, np.inf), method="bvls")
        if not sol.success:
            raise SolverFailure(f"the least-squares refit did not converge ({sol.message})")
        scaled[idx] = sol.x
        return scaled
    eliminated = _tied_bounded_least_squares(reduced, names, idx, lower, ties)
    if eliminated is not None:
        scaled[idx] = eliminated
        return scaled
    c = cp.Variable(idx.size)
    where = {names[i]: j for j, i in enumerate(idx)}
    cons = [c[j] >= 0 for j, lo in enumerate(lower) if lo == 0]
    cons += [c[where[a]] == _tie_factor(reduced, names, a, b, f) * c[where[b]] for a, b, f in ties]
    problem = cp.Problem(cp.Minimize(cp.sum_squares(reduced.R[:, idx] @ c - reduced.r)), cons)
    failures = []
    for solver in fallbacks("CLARABEL"):
        try:
            problem.solve(solver=solver, warm_start=False, **SOLVER_SETTINGS[solver])
        except cp.error.SolverError as exc:
            failures.append(f"{solver}: {exc}")
            continue
        if problem.status == cp.OPTIMAL and c.value is not None:
            break
        failures.append(f"{solver}: status '{problem.status}'"
                        + (" (infeasible, though all zero satisfies the signs and ties: a numerical failure)"
                           if problem.status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE) else ""))
    else:
        raise SolverFailure(f"the tied least-squares refit failed with every solver ({'; '.join(failures)}); "
                            "rescale the data or drop a tie")
    if failures:
        warnings.warn(f"tied least-squares refit: {'; '.join(failures)}; {solver} answered instead", CvxidWarning,
                      stacklevel=2)
    scaled[idx] = c.value
    return scaled
