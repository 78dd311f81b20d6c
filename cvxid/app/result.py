"""What one run produced: :class:`RunResult`, for a system of :math:`N \\ge 1` equations.

It prints (``summary``), tabulates (``table``: physical parameters beside the truth) and
serialises itself (``to_dict``: the ``result.json`` schema 1, whose keys for one equation
and for a coupled system are listed in ``docs/spec.md``).  For one equation its
``model`` is that equation's :class:`~cvxid.identified.IdentifiedModel`; for several,
``system`` holds them all.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd

from cvxid.app.report import records
from cvxid.data.experiment import Experiment
from cvxid.diagnosis.compare import Comparison
from cvxid.diagnosis.ranking import Diagnosis
from cvxid.diagnosis.refine import Refinement
from cvxid.errors import CvxidError
from cvxid.metrics import relative_error_percent
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.identify.bootstrap import Bootstrap
from cvxid.identify.given import GivenCheck, checked_line
from cvxid.identify.selection import Stability
from cvxid.identify.orders import OrderSearch
from cvxid.identify.output_error import PolishResult
from cvxid.identify.path import Path
from cvxid.identify.problem import Problem
from cvxid.identify.stepwise import Pruning, Stepwise
from cvxid.regression.windows import Windows
from cvxid.regression.algebraic import AlgebraicOrders
from cvxid.spec.problem import ProblemSpec

RESULT_SCHEMA = 1


@dataclass
class RunResult:
    """Everything one run produced."""

    spec: ProblemSpec
    system: IdentifiedSystem
    path: Path | None
    problem: Problem | None
    train: Experiment
    test: Experiment | None
    test_mse: float
    test_nmse: float
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)
    bootstrap: Bootstrap | None = None
    order_search: OrderSearch | None = None
    tau: dict | None = None
    polish: PolishResult | None = None
    diagnosis: Diagnosis | None = None  # the first ranking of the missing effects
    refinement: Refinement | None = None  # the add-an-effect loop
    velocity_scores: dict | None = None
    stepwise: Stepwise | None = None
    lam: float | None = None  # the selected lambda (None: least squares, nothing selected)
    window: Windows | None = None  # the algebraic operation's windows (None: the whole record)
    comparisons: dict[str, Comparison] | None = None  # the test record's free run and k-step fit, by coordinate
    train_comparisons: dict[str, Comparison] | None = None  # the training record's, from the polish's start
    input_delay: dict | None = None  # the input's delay estimated: estimate, interval, method
    simulation_refinement: object | None = None  # SimulationRefinement: the diagnosis by simulation error
    stability: Stability | None = None  # stability selection's inclusion probabilities
    pruning: Pruning | None = None  # [fit] prune: the selected terms pruned by simulation error
    unpolished: IdentifiedSystem | None = None  # the model the output-error polish started from
    given: tuple[GivenCheck, ...] = ()  # the values the spec gives, tested against the record after the polish

    @property
    def coupled(self) -> bool:
        return len(self.system.models) > 1

    @property
    def model(self) -> IdentifiedModel:
        """The identified equation (one-equation runs; a coupled run has ``system``)."""
        if self.coupled:
            raise CvxidError(f"this run identified {len(self.system.models)} coupled equations: use result.system")
        return self.system.single

    @property
    def physical(self) -> dict[str, float]:
        return self.system.physical

    @property
    def test_fit(self) -> Comparison | pd.DataFrame | None:
        """The test comparison: one equation's :class:`~cvxid.diagnosis.compare.Comparison`;
        for several, a table by coordinate (``fit_percent``, ``rms``, ``record_fit_percent``,
        ``initial_position``, ``initial_velocity``, ``noise_ceiling_percent``,
        ``k_step_fit_percent``; a diverged simulation's fit is -inf, its RMS inf)."""
        return self._fit_view(self.comparisons)

    @property
    def train_fit(self) -> Comparison | pd.DataFrame | None:
        """The polished model against the training record it was fitted on, from the
        polish's own initial state, as :attr:`test_fit` shows the test record's (None
        without the output-error polish)."""
        return self._fit_view(self.train_comparisons)

    def _fit_view(self, comparisons: dict[str, Comparison] | None) -> Comparison | pd.DataFrame | None:
        if comparisons is None:
            return None
        if not self.coupled:
            return next(iter(comparisons.values()))
        rows = {c: {"fit_percent": -np.inf if m.fit_percent is None else m.fit_percent,
                    "rms": np.inf if m.rms is None else m.rms,
                    "record_fit_percent": -np.inf if m.record_fit_percent is None else m.record_fit_percent,
                    "initial_position": np.nan if m.initial_state is None else m.initial_state[0],
                    "initial_velocity": np.nan if m.initial_state is None else m.initial_state[1],
                    "noise_ceiling_percent": m.ceiling_percent,
                    "k_step_fit_percent": np.nan if m.k_step_fit_percent is None else m.k_step_fit_percent}
                for c, m in comparisons.items()}
        return pd.DataFrame.from_dict(rows, orient="index").rename_axis("coordinate")

    # ------------------------------------------------------------------ tables
    def table(self) -> pd.DataFrame:
        """Physical parameters, beside the truth when the spec has one (and the output-error
        standard errors of a coupled run)."""
        truth = self.spec.truth.physical if self.spec.truth else None
        if not self.coupled:
            frame = self.model.table(truth)
        else:
            frame = pd.DataFrame({"estimate": self.physical})
            if truth is not None:
                frame["truth"] = pd.Series(truth, dtype=float).reindex(frame.index, fill_value=0.0)
                frame["error %"] = relative_error_percent(frame["estimate"], frame["truth"])
        if self.polish is not None:
            names = {k: self._key(k) for k in self.polish.parameters}
            frame["std error"] = pd.Series({names[k]: v for k, v in self.polish.standard_errors.items()}) \
                .reindex(frame.index)
            bounds = {names[k]: self.polish.physical_interval(k) for k in self.polish.parameters}
            frame["95 % low"] = pd.Series({k: v[0] for k, v in bounds.items()}).reindex(frame.index)
            frame["95 % high"] = pd.Series({k: v[1] for k, v in bounds.items()}).reindex(frame.index)
        return frame

    def _key(self, parameter: str) -> str:
        """A polished parameter's key in ``result.json``: the key of :attr:`physical` (a
        coupled system's polish names its columns ``equation:column``; one equation's are
        already its physical names)."""
        return self._physical_name(parameter) if self.coupled else parameter

    def _physical_name(self, column: str) -> str:
        """The physical name of a coupled system's column ``equation:column`` (its ``names``,
        ``equation:m`` for an inertia), else the column itself."""
        if column == "tau":
            return "tau"
        label, _, name = column.partition(":")
        spec = self.system.specs.get(label)
        if spec is None:
            return column
        pname, _ = spec.named_parameter(name)
        if pname != name:
            return pname
        return f"{label}:m" if name == spec.inertia_term.name else column

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict:
        fit = self.spec.fit
        common = {
            "schema": RESULT_SCHEMA,
            "name": self.spec.name,
            "coefficients": {k: float(v) for k, v in self.system.coefficients.items()},
            "physical": {k: float(v) for k, v in self.physical.items()},
            "truth": self.spec.truth.physical if self.spec.truth else None,
            "test_mse": self.test_mse,
            "estimator": fit.estimator,
            "velocity": fit.velocity,
            "velocity_scores": self.velocity_scores,
            "window": "record" if self.window is None else self.window.as_dict(),
            "seconds": self.seconds,
            "warnings": self.warnings,
            "tau": self.tau,
            "input_delay": self.input_delay,
            "stability": None if self.stability is None else self.stability.as_dict(),
            "bootstrap": None if self.bootstrap is None else {
                "samples": len(self.bootstrap.coefficients),
                "resample": self.bootstrap.settings.resample,
                "fraction": self.bootstrap.settings.fraction,
                "rows_per_sample": self.bootstrap.size,
                "block_share": self.bootstrap.share,
                "terms": records(self.bootstrap.summary()),
                **({"physical": records(self.bootstrap.physical_summary())}
                   if self.bootstrap.physical is not None else {}),
            },
            "polish": None if self.polish is None else {
                "method": "output_error",
                "rms_before": self.polish.rms_before,
                "rms_after": self.polish.rms_after,
                "jacobian_spread": self.polish.jacobian_spread,
                "jacobian_spread_at": self.polish.jacobian_spread_at,
                "input_noise_inflation": self.polish.input_noise_inflation,
                "longer_delay": None if self.polish.longer_delay is None else asdict(self.polish.longer_delay),
                "given": [{**check.as_dict(), "name": self._key(check.name)} for check in self.given],
                "standard_errors": {self._key(name): se for name, se in self.polish.standard_errors.items()},
                "intervals": {self._key(name): list(self.polish.physical_interval(name))
                              for name in self.polish.parameters},
                "seconds": self.polish.seconds,
            },
            "diagnosis": None if self.diagnosis is None else {
                "ranking": self.diagnosis.records(),
                "groups": self.diagnosis.groups,
            },
            "refinement": None if self.refinement is None else [s.as_dict() for s in self.refinement.steps],
            "refinement_stopped": None if self.refinement is None else self.refinement.stopped,
            "simulation_diagnosis": None if self.simulation_refinement is None else {
                "ranking": self.simulation_refinement.rankings[0].reset_index().to_dict(orient="records")
                if self.simulation_refinement.rankings else [],
                "steps": [s.as_dict() for s in self.simulation_refinement.steps],
                "at_precision": self.simulation_refinement.at_precision,
            },
            "stepwise": None if self.stepwise is None else {
                "history": self.stepwise.history.to_dict(orient="records"),
                "noise": self.stepwise.noise,
                "seconds": self.stepwise.seconds,
            },
            "pruning": None if self.pruning is None else {
                "removed": self.pruning.removed,
                "added": self.pruning.added,
                "history": self.pruning.history.to_dict(orient="records"),
                "noise": self.pruning.noise,
                "seconds": self.pruning.seconds,
            },
            "order_search": None if self.order_search is None else {
                "best_order": self.order_search.best_order,
                "table": records(self.order_search.table),
            },
            **self._test_fits(),
        }
        return common | (self._coupled_dict() if self.coupled else self._single_dict())

    def _test_fits(self) -> dict:
        """The test record's comparison for ``result.json``, and the training record's fit
        and noise ceiling: each figure by coordinate, squeezed to its value for one equation
        (as its columns are printed bare)."""
        test = {"test_fit_percent": "fit_percent", "test_rms": "rms",
                "test_fit_percent_record_start": "record_fit_percent",
                "test_fit_percent_noise_ceiling": "ceiling_percent", "test_k_step_fit_percent": "k_step_fit_percent"}
        train = {"train_fit_percent": "fit_percent", "train_fit_percent_noise_ceiling": "ceiling_percent"}
        cmps = self.comparisons
        first = None if cmps is None else next(iter(cmps.values()))
        return _by_coordinate(cmps, test) | _by_coordinate(self.train_comparisons, train) | {
            "test_initial_state": None if first is None or first.initial_state is None else {
                "method": first.initial, "position": {c: m.initial_state[0] for c, m in cmps.items()},
                "velocity": {c: m.initial_state[1] for c, m in cmps.items()}}}

    def _single_dict(self) -> dict:
        model, fit = self.model, self.spec.fit
        return {
            "equation": model.equation(),
            "equation_latex": model.equation_latex(),
            "regression_equation": model.regression_equation(),
            "support": model.support,
            "ties": self._ties(),
            "test_nmse": self.test_nmse,
            "lambda": model.lam,
            "selection": fit.selection,
            "algebraic_orders": vars(AlgebraicOrders.for_model(self.spec.model)),
            "solver": self.problem.solver,
            "loss": fit.loss,
            "coupled": False,
        }

    def _ties(self) -> list[dict]:
        """The ties the coefficients hold (a chain as a star: every tied column a multiple of
        the chain's last)."""
        return [{"left": a, "right": b, "factor": f} for a, b, f in self.system.ties]

    def _tie_lines(self) -> list[str]:
        return [f"  tie: {a} = {f:g} {b}" for a, b, f in self.system.ties]

    def _coupled_dict(self) -> dict:
        system = self.system
        return {
            "coupled": True,
            "equation": "; ".join(system.equations()),
            "equations": {label: m.equation() for label, m in system.models.items()},
            "equation_latex": {label: m.equation_latex() for label, m in system.models.items()},
            "regression_equation": {label: m.regression_equation() for label, m in system.models.items()},
            "support": [k for k, v in system.coefficients.items() if v != 0.0],
            "ties": self._ties(),
            "test_nmse": self.test_nmse,
            "lambda": self.lam,
            "selection": self.spec.fit.selection,
            "algebraic_orders": {label: vars(AlgebraicOrders.for_model(m.spec)) for label, m in system.models.items()},
            "solver": self.spec.fit.solver,
            "loss": self.spec.fit.loss,
        }

    # ------------------------------------------------------------------ printing
    def summary(self) -> str:
        return self._coupled_summary() if self.coupled else self._single_summary()

    def _windows(self) -> str:
        return "whole-record integrals" if self.window is None else str(self.window)

    def _single_summary(self) -> str:
        frame = self.table()
        apart = self._bootstrap_apart()
        if self.bootstrap is not None and self.bootstrap.physical is not None and not apart:
            spread = self.bootstrap.physical_summary()
            frame["boot std"] = spread["std"].reindex(frame.index)
        fit = self.spec.fit
        lines = [
            f"cvxid: {self.spec.name}",
            f"  identified: {self.model.equation()}",
            f"  support ({len(self.model.support)}): {', '.join(self.model.support)}",
            *self._tie_lines(),
            f"  lambda = {self.model.lam:.3g} ({fit.estimator}, solver {self.problem.solver}, "
            f"velocity {fit.velocity}, {self._windows()})",
            (f"  test MSE = {self.test_mse:.4g}  (relative {self.test_nmse:.3g})" if self.test is not None
             else "  test MSE: no test experiment ([data.test]) to score on"),
            *([f"  test {self.test_fit.title()}; {self.test_fit.k_step}-step fit "
               + ("-" if self.test_fit.k_step_fit_percent is None else f"{self.test_fit.k_step_fit_percent:.1f} %")]
              if self.test_fit is not None else []),
            *([f"  training record (fitted) {self.train_fit.title()}"] if self.train_fit is not None else []),
            *([f"  tau = {self.tau['estimate']:.5g} ({self.tau['method']}"
               + (f", 95 % interval {self.tau['interval'][0]:.5g} … {self.tau['interval'][1]:.5g})"
                  if self.tau["interval"] and all(v is not None and np.isfinite(v) for v in self.tau["interval"])
                  else ", no interval)")]
              if self.tau else []),
            *([f"  tau_u = {self.input_delay['estimate']:.5g} (input delay, {self.input_delay['method']}"
               + (f", 95 % interval {self.input_delay['interval'][0]:.5g} … {self.input_delay['interval'][1]:.5g})"
                  if self.input_delay["interval"] else ")")] if self.input_delay else []),
            *([f"  {self.polish.summary()}"] if self.polish else []),
            *([f"  {checked_line(self.given)}"] if self.given else []),
            "",
            frame.to_string(float_format=lambda v: f"{v:.5g}", na_rep="–"),  # (significant digits: a mass of
            #                                                              1e-3 reads; – where nothing was estimated)
            *(["  (–: not estimated by that method: a parameter given in the spec, a term held at its sign "
               "constraint's bound 0 (a warning names it), or an input's delay the bootstrap holds)"]
              if frame.drop(columns=[c for c in ("truth", "error %") if c in frame]).isna().to_numpy().any() else []),
            *([f"  (the bootstrap's spreads, in result.json, are of the equation-error model {apart})"]
              if self.bootstrap is not None and apart else []),
            "",
        ]
        return "\n".join(lines + self._sections() + self._footer())

    def _bootstrap_apart(self) -> str:
        """What stands between the bootstrapped model and the printed estimates ("" when
        nothing does): its spreads are then not printed beside them."""
        if any(r is not None and r.steps for r in (self.refinement, self.simulation_refinement)):
            return "before the diagnosis added effects"
        return "before the output-error polish" if self.polish is not None else ""

    def _coupled_summary(self) -> str:
        system = self.system
        lines = [f"cvxid: {self.spec.name} ({len(system.models)} coupled equations, identified jointly)"]
        lines += [f"  {m.equation()}" for m in system.models.values()]
        lines += self._tie_lines()
        lines.append(f"  algebraic operation: {self._windows()}")
        lines.append(f"  tau = {system.tau:.5g}"
                     + (f" ± {1.96 * self.polish.standard_errors['tau']:.2g} (95 %, output error)" if self.polish else ""))
        if self.test is not None:
            table = self.test_fit
            fits = ", ".join(f"{c} {v:.1f} %" for c, v in table["fit_percent"].items())
            own = ", ".join(f"{c} {v:.1f} %" for c, v in table["record_fit_percent"].items())
            ahead = ", ".join(f"{c} {v:.1f} %" for c, v in table["k_step_fit_percent"].items())
            lines.append(f"  test: equation-error MSE {self.test_mse:.4g}; free-run fit {fits} (initial state "
                         f"estimated; {own} from the record's own start); k-step fit {ahead}")
        else:
            lines.append("  test: no test experiment ([data.test]) to score on")
        if self.polish is not None:
            lines.append(f"  {self.polish.summary()}")
        if self.given:
            lines.append(f"  {checked_line(self.given)}")
        if self.bootstrap is not None:
            b, apart = self.bootstrap, self._bootstrap_apart()
            lines.append(f"  bootstrap: {len(b.coefficients)} samples of {100 * b.settings.fraction:.3g} % of the rows "
                         f"({b.settings.resample}); each term's mean, spread and inclusion in result.json"
                         + (f", of the equation-error model {apart}" if apart else ""))
        lines += ["", self.table().to_string(float_format=lambda v: f"{v:.5g}"), ""]
        return "\n".join(lines + self._sections() + self._footer())

    def _sections(self) -> list[str]:
        """Each stage the run went through, as it prints itself."""
        lines = []
        for part in (self.stability, self.order_search, self.stepwise, self.pruning, self.diagnosis, self.refinement,
                     self.simulation_refinement):
            if part is not None:
                lines += [repr(part), ""]
        return lines

    def _footer(self) -> list[str]:
        return [f"  {self.seconds:.1f} s"] + [f"  warning: {w}" for w in self.warnings]

    def __repr__(self) -> str:
        return self.summary()


def _by_coordinate(comparisons: dict[str, Comparison] | None, keys: dict[str, str]) -> dict:
    """``result.json``'s figures (key → the :class:`~cvxid.diagnosis.compare.Comparison`
    attribute) by coordinate, a single coordinate's squeezed to its value; None without
    comparisons."""
    if comparisons is None:
        return dict.fromkeys(keys)
    squeeze = (lambda values: next(iter(values.values()))) if len(comparisons) == 1 else (lambda values: values)
    return {key: squeeze({c: getattr(m, attribute) for c, m in comparisons.items()}) for key, attribute in keys.items()}
