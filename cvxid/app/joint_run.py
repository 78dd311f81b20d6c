"""The main job for a coupled spec: identify every equation jointly, diagnose, polish, report.

``run_joint(spec)``: load or simulate the experiments; identify all equations in one
problem with the shared delay profiled (:func:`~cvxid.identify.joint.identify_joint`); with
``estimator = "lasso"`` or ``"stlsq"`` select each equation's terms on a λ path scored by
the joint test error; with ``[diagnose]``, rank missing effects and add them while the
errors fall (:func:`~cvxid.diagnose.joint.refine_joint`); with ``refine =
"output_error"``, polish by the simulation error of every coordinate.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from cvxid.app.report import plain, prepare_folder, records
from cvxid.data.experiment import Experiment
from cvxid.diagnose.joint import JointRefinement, refine_joint
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identify.bootstrap import Bootstrap, bootstrap
from cvxid.identify.joint import (
    JointPolish,
    JointRegression,
    JointResult,
    identify_joint,
    joint_models,
    joint_test_mse,
    polish_joint,
)
from cvxid.identify.loss import huber_refit
from cvxid.identify.path import Path as LambdaPath
from cvxid.model.library import Library
from cvxid.regression.builder import SystemBuilder
from cvxid.spec.coupled import JointProblemSpec, joint_physical

RESULT_SCHEMA = 1


@dataclass
class JointRunResult:
    """Everything one coupled run produced."""

    spec: JointProblemSpec
    result: JointResult
    train: Experiment
    test: Experiment | None
    test_mse: float
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)
    path: LambdaPath | None = None
    refinement: JointRefinement | None = None
    polish: JointPolish | None = None
    bootstrap: Bootstrap | None = None

    @property
    def physical(self) -> dict[str, float]:
        coefs = {label: m.coefficients for label, m in self.result.models.items()}
        return joint_physical(self.result.specs, coefs, self.result.tau)

    def table(self) -> pd.DataFrame:
        frame = pd.DataFrame({"estimate": self.physical})
        if self.spec.truth is not None:
            truth = pd.Series(self.spec.truth.physical)
            frame["truth"] = truth.reindex(frame.index)
            frame["error %"] = 100 * (frame["estimate"] / frame["truth"] - 1)
        if self.polish is not None:
            se = {self._physical_name(k): v for k, v in self.polish.standard_errors.items()}
            frame["std error"] = pd.Series(se).reindex(frame.index)
        return frame

    def _physical_name(self, column: str) -> str:
        if column == "tau":
            return "tau"
        label, _, name = column.partition(":")
        spec = self.result.specs.get(label)
        if spec is None:
            return column
        pname, _ = spec.named_parameter(name)
        if pname != name:
            return pname
        return f"{label}:m" if name == spec.inertia_term.name else column

    def comparison(self) -> pd.DataFrame | None:
        return self.result.compare(self.test) if self.test is not None else None

    def to_dict(self) -> dict:
        cmp = self.comparison()
        tau = {"estimate": self.result.tau, "interval": self.result.info.get("tau_interval"), "method": "joint profile"}
        if self.polish is not None:
            se = self.polish.standard_errors["tau"]
            tau = {"estimate": self.result.tau, "interval": [self.result.tau - 1.96 * se, self.result.tau + 1.96 * se],
                   "method": "output_error"}
        return {
            "schema": RESULT_SCHEMA,
            "name": self.spec.name,
            "coupled": True,
            "equation": "; ".join(self.result.equations()),
            "equations": {label: m.equation() for label, m in self.result.models.items()},
            "equation_latex": {label: m.equation_latex() for label, m in self.result.models.items()},
            "coefficients": {k: float(v) for k, v in self.result.coefficients.items()},
            "physical": {k: float(v) for k, v in self.physical.items()},
            "truth": self.spec.truth.physical if self.spec.truth else None,
            "support": [k for k, v in self.result.coefficients.items() if v != 0.0],
            "ties": [{"left": a, "right": b, "factor": f} for a, b, f in self.result.ties],
            "test_mse": self.test_mse,
            "test_fit_percent": None if cmp is None else {c: float(v) for c, v in cmp["fit_percent"].items()},
            "lambda": None if self.path is None else float(self.result.info.get("lambda", 0.0)),
            "estimator": self.spec.fit.estimator,
            "velocity": self.spec.fit.velocity,
            "solver": self.spec.fit.solver,
            "seconds": self.seconds,
            "warnings": self.warnings,
            "tau": tau,
            "diagnosis": None if not (self.refinement and self.refinement.rankings) else {
                "ranking": self.refinement.rankings[0].reset_index().to_dict(orient="records"),
            },
            "refinement": None if self.refinement is None else self.refinement.steps,
            "bootstrap": None if self.bootstrap is None else {
                "samples": len(self.bootstrap.coefficients),
                "terms": records(self.bootstrap.summary()),
            },
            "loss": self.spec.fit.loss,
            "polish": None if self.polish is None else {
                "method": "output_error", "rms_before": self.polish.rms_before, "rms_after": self.polish.rms_after,
                "standard_errors": self.polish.standard_errors, "seconds": self.polish.seconds,
            },
        }

    def summary(self) -> str:
        lines = [f"cvxid: {self.spec.name} ({len(self.result.models)} coupled equations, identified jointly)"]
        lines += [f"  {m.equation()}" for m in self.result.models.values()]
        lines += [f"  tie: {a} = {f:g} {b}" for a, b, f in self.result.ties]
        lines.append(f"  tau = {self.result.tau:.5g}"
                     + (f" ± {1.96 * self.polish.standard_errors['tau']:.2g} (95 %, output error)" if self.polish else ""))
        if self.test is not None:
            cmp = self.comparison()
            fits = ", ".join(f"{c} {v:.1f} %" for c, v in cmp["fit_percent"].items())
            lines.append(f"  test: equation-error MSE {self.test_mse:.4g}; free-run fit {fits}")
        else:
            lines.append("  test: no test experiment ([data.test]) to score on")
        if self.polish is not None:
            lines.append(f"  output-error polish: simulation RMS {self.polish.rms_before:.4g} -> "
                         f"{self.polish.rms_after:.4g} in {self.polish.seconds:.1f} s")
        lines += ["", self.table().to_string(float_format=lambda v: f"{v:.5g}"), ""]
        if self.refinement is not None:
            lines += [repr(self.refinement), ""]
        lines.append(f"  {self.seconds:.1f} s")
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def __repr__(self) -> str:
        return self.summary()

    def write(self, out) -> Path:
        """``result.json``, ``report.md``, ``model.json`` (the joint model, for
        :meth:`~cvxid.identify.joint.JointResult.load`) and figures (``test_fit``, ``delay_profile``,
        ``refinement``) in ``out``."""
        out = prepare_folder(out)
        data = self.to_dict()
        figures = {"delay_profile": self._profile_figure}
        if self.test is not None:
            figures["test_fit"] = self._fit_figure
        if self.refinement is not None and self.refinement.steps:
            figures["refinement"] = self.refinement.plot
        written = {}
        for name, plot in figures.items():
            fig = plot()
            fig.savefig(out / f"{name}.png", dpi=110)
            plt.close(fig)
            written[name] = f"{name}.png"
        data["figures"] = written
        self.result.save(out / "model.json")  # reload with cvxid.identify.joint.JointResult.load
        data["model_file"] = "model.json"
        (out / "result.json").write_text(json.dumps(plain(data), indent=2, allow_nan=False))
        md = [f"# {self.spec.name}", "", "```", self.summary(), "```", ""] + [f"![{k}]({v})" for k, v in written.items()]
        (out / "report.md").write_text("\n".join(md) + "\n")
        return out / "result.json"

    def _fit_figure(self):
        sim = self.result.simulate(self.test)
        coords = list(sim)
        fig, axes = plt.subplots(len(coords), 1, figsize=(8, 2.6 * len(coords)), sharex=True)
        for ax, c in zip(np.atleast_1d(axes), coords):
            ax.plot(self.test.time, self.test.output(c), "k", lw=0.8, label="measured")
            ax.plot(self.test.time, sim[c], "r", lw=1.0, label="identified model")
            ax.set_ylabel(c)
        axes[0].legend()
        axes[0].set_title("free-run simulation of the test experiment")
        axes[-1].set_xlabel("time [s]")
        fig.tight_layout()
        return fig

    def _profile_figure(self):
        taus, values = self.result.profile
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.semilogy(taus, values, "k.-")
        ax.axvline(self.result.tau, color="r", ls="--", lw=1, label=f"tau = {self.result.tau:.4g}")
        ax.set_xlabel("delay tau [s]")
        ax.set_ylabel("joint equation-error MSE")
        ax.legend()
        fig.tight_layout()
        return fig


def run_joint(spec: JointProblemSpec) -> JointRunResult:
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CvxidWarning)
        out = _identify(spec)
    out.warnings = list(dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, CvxidWarning)))
    out.seconds = time.perf_counter() - start
    return out


def _identify(spec: JointProblemSpec) -> JointRunResult:
    fit = spec.fit
    train = spec.experiment("train")
    test = spec.experiment("test") if "test" in spec.data else None
    velocity, window = fit.velocity, fit.window
    rows = SystemBuilder(spec.equations, train, velocity, window)
    test_rows = SystemBuilder(spec.equations, test, velocity, window) if test is not None else None
    joint = JointRegression(spec.equations, rows, ties=spec.ties)
    result = joint.identify()
    path = ensemble = None
    if fit.estimator != "lstsq":
        result, path = _select(spec, joint, result, test_rows)
    if fit.bootstrap or fit.loss == "huber":
        result, ensemble = _resample_or_robust(spec, joint, result, test_rows)
    refinement = None
    if spec.diagnose is not None:
        if test is None:
            raise CvxidError("[diagnose] scores effects on the test data: add [data.test]")
        d = spec.diagnose
        refinement = refine_joint(result, train, test, d.candidates, d.min_improvement,
                                  d.max_steps if d.refine else 0, velocity, window, (rows, test_rows))
        result = refinement.result
    polished = None
    if fit.refine == "output_error":
        polished = polish_joint(result, train)
        result = polished.result
    test_mse = joint_test_mse(result, test_rows) if test is not None else float("nan")
    return JointRunResult(spec, result, train, test, test_mse, path=path, refinement=refinement, polish=polished,
                          bootstrap=ensemble)


def _select(spec: JointProblemSpec, joint: JointRegression, result: JointResult, test_rows: SystemBuilder | None):
    """The λ path of the joint problem at the profiled delay, scored by the joint test
    equation error; the chosen support is identified again (delay profiled anew)."""
    fit = spec.fit
    if test_rows is None:
        raise CvxidError(f"estimator = '{fit.estimator}' selects terms by the test error: add [data.test]")
    validation = JointRegression(spec.equations, test_rows).at(result.tau)
    path = LambdaPath.compute(joint.problem(result.tau), fit.lambdas, validation.residual, fit.estimator, fit.debias)
    best = path.best(fit.selection)
    chosen = {n for n, keep in zip(path.names, best.support) if keep}
    specs = {}
    for label, s in spec.equations.items():
        terms = [t for t in s.library if f"{label}:{t.name}" in chosen]
        specs[label] = s.with_library(Library(terms))
    names = {f"{label}:{n}" for label, s in specs.items() for n in s.column_names}
    ties = tuple(t for t in spec.ties if t[0] in names and t[1] in names)
    selected = identify_joint(specs, joint.rows, ties)
    return replace(selected, info=dict(selected.info, **{"lambda": best.lam})), path


def _resample_or_robust(spec: JointProblemSpec, joint: JointRegression, result: JointResult,
                        test_rows: SystemBuilder | None):
    """``[fit] bootstrap``: the ensemble of the joint problem at the identified delay
    (resampled rows, the estimator's path on each, ties and signs kept); its mean is the
    estimate (the paper's eq. 18).  ``loss = "huber"``: the robust refit of the support."""
    fit = spec.fit
    tied = JointRegression(result.specs, joint.rows, ties=result.ties)
    regression = tied.at(result.tau)
    coefficients = result.coefficients
    keep = np.array([coefficients.get(n, 0.0) != 0.0 for n in regression.names])
    ensemble = None
    if fit.bootstrap:
        validation = JointRegression(result.specs, test_rows).at(result.tau) if test_rows is not None else None
        ensemble = bootstrap(regression, fit.lambdas, validation.residual if validation is not None else None,
                             fit.bootstrap, tied.nonnegative, fit.solver, fit.estimator, fit.debias, fit.selection,
                             ties=result.ties)
        coefficients = dict(ensemble.mean)
        keep = np.array([coefficients[n] != 0.0 for n in regression.names])
    if fit.loss == "huber":
        robust, _ = huber_refit(regression, keep, tied.nonnegative, fit.solver, ties=result.ties)
        coefficients = dict(zip(regression.names, np.where(keep, robust.coefficients, 0.0)))
    models = joint_models(result.specs, {k: float(v) for k, v in coefficients.items()}, result.tau, result.info)
    return replace(result, models=models), ensemble
