"""The result of an identification: :class:`IdentifiedModel`.

It holds the regression coefficients, the physical parameters they map to, the selected
support, and can print its equation, simulate itself and tabulate itself.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError
from cvxid.model.equation import ModelSpec
from cvxid.model.terms import latex_symbol
from cvxid.simulate import System, simulate

SCHEMA = "cvxid.identified/1"


@dataclass(frozen=True)
class IdentifiedModel:
    """An identified model: the spec plus numbers.

    Attributes
    ----------
    spec : ModelSpec
        The model that was identified.
    coefficients : dict
        Regression coefficients by column name (zero off the support).
    lam : float
        The selected :math:`\\lambda`.
    info : dict
        Extra figures of the fit (test error, solver, …).
    """

    spec: ModelSpec
    coefficients: dict[str, float]
    lam: float = 0.0
    info: dict = field(default_factory=dict)
    tau: float | None = None  # the delay an exact-delay regression was built for

    @property
    def support(self) -> list[str]:
        return [n for n, c in self.coefficients.items() if c != 0.0]

    @property
    def physical(self) -> dict[str, float]:
        return self.spec.physical(self.coefficients, self.tau)

    def system(self, history: str | None = None) -> System:
        """The identified system, ready to simulate (terms off the support dropped)."""
        mass, terms, tau, gain = self.spec.physical_terms(self.coefficients, self.tau)
        lib = [t for t in self.spec.library if terms[t.name] != 0.0]
        delay = self.spec.delay
        history = history or (delay.history if delay else "zero")
        return System(
            terms=tuple(lib),
            coefficients=np.array([terms[t.name] for t in lib]),
            mass=mass,
            coordinate=self.spec.coordinate,
            gain=gain or 0.0,
            tau=tau or 0.0,
            derivative=delay.derivative if delay else 0,
            history=history,
        )

    def equation(self) -> str:
        """The identified equation in physical form, e.g.
        ``0.99 x'' + 1.06 x' + … = f + 2 x(t - 0.166)``."""
        text = self.system().equation().replace(" = f", f" = {self.spec.input}", 1)
        delay = self.spec.delay
        if delay is not None and delay.coordinate != self.spec.coordinate:  # fed back from another coordinate
            own = self.spec.coordinate + "'" * delay.derivative
            text = text.replace(f" {own}(t - ", f" {delay.signal}(t - ")
        return text

    def equation_latex(self) -> str:
        """The identified equation in LaTeX."""
        system = self.system()
        accel = latex_symbol(self.spec.coordinate + "''")
        lhs = f"{float(system.mass):.6g}\\,{accel}"
        for term, c in zip(system.terms, np.atleast_1d(system.coefficients)):
            lhs += f" {'-' if c < 0 else '+'} {abs(c):.6g}\\,{term.latex}"
        rhs = self.spec.input
        if system.gain:
            gain, signal = float(system.gain), latex_symbol(self.spec.delay.signal)
            rhs += f" {'-' if gain < 0 else '+'} {abs(gain):.6g}\\,{signal}(t - {float(system.tau):.6g})"
        return f"{lhs} = {rhs}"

    def regression_equation(self) -> str:
        """The identified regression, column by column (delay terms unresolved)."""
        parts = [f"{c:+.6g} {n}" for n, c in self.coefficients.items() if c != 0.0]
        return " ".join(parts) + f" = {self.spec.input}"

    def simulate(self, experiment: Experiment, x0: float, v0: float, history: str | None = None):
        """Free-run simulation under the experiment's measured input."""
        return simulate(self.system(history), experiment.time, experiment.input(self.spec.input), x0, v0)

    def table(self, truth: dict[str, float] | None = None) -> pd.DataFrame:
        """Physical parameters, beside the truth when it is known."""
        phys = self.physical
        frame = pd.DataFrame({"estimate": pd.Series(phys)})
        if truth:
            frame["truth"] = pd.Series({k: truth.get(k, np.nan) for k in phys})
            frame["error %"] = 100 * (frame["estimate"] - frame["truth"]) / frame["truth"].abs()
        frame.index.name = "parameter"
        return frame

    def __repr__(self) -> str:
        lines = [
            "IdentifiedModel",
            f"  {self.equation()}",
            f"  support: {', '.join(self.support)}",
            f"  lambda = {self.lam:.3g}",
        ]
        lines += [f"  {k} = {v:.6g}" for k, v in self.physical.items()]
        return "\n".join(lines)

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict:
        """A JSON-ready description (schema ``cvxid.identified/1``); user-defined Python
        terms cannot be written and are refused."""
        from cvxid.model.terms import FunctionTerm

        spec = self.spec
        if any(isinstance(t, FunctionTerm) for t in spec.library):
            raise CvxidError("a model with user-defined Python terms cannot be saved as JSON")
        delay = spec.delay
        return {
            "schema": SCHEMA,
            "model": {
                "coordinate": spec.coordinate,
                "others": list(spec.others),
                "input": spec.input,
                "inertia": spec.inertia,
                "mass": spec.mass,
                "library": spec.library.names,
                "delay": None if delay is None else {
                    "coordinate": delay.coordinate, "derivative": delay.derivative, "gain": delay.gain, "taylor_order": delay.taylor_order,
                    "method": delay.method, "tau_min": delay.tau_min, "tau_max": delay.tau_max,
                    "history": delay.history,
                },
                "nonnegative": list(spec.nonnegative),
                "names": dict(spec.names),
                "orders": list(spec.orders),
            },
            "coefficients": {k: float(v) for k, v in self.coefficients.items()},
            "lambda": float(self.lam),
            "tau": None if self.tau is None else float(self.tau),
        }

    @classmethod
    def from_dict(cls, data: dict) -> "IdentifiedModel":
        """Rebuild a model written by :meth:`to_dict`, checking every field."""
        from cvxid.model.delay import DelayedFeedback
        from cvxid.model.library import Library
        from cvxid.model.terms import parse_term

        try:
            if data.get("schema") != SCHEMA:
                raise CvxidError(f"not a cvxid model file (schema {data.get('schema')!r}, expected {SCHEMA!r})")
            m = data["model"]
            coord = str(m["coordinate"])
            others = tuple(str(o) for o in m.get("others", ()))
            delay = None
            if m["delay"] is not None:
                d = m["delay"]
                delay = DelayedFeedback(str(d.get("coordinate", coord)), int(d["derivative"]), d["gain"], int(d["taylor_order"]), str(d["method"]),
                                        float(d["tau_max"]), float(d["tau_min"]), str(d["history"]))
            spec = ModelSpec(
                library=Library(parse_term(n, (coord, *others)) for n in m["library"]),
                coordinate=coord, input=str(m["input"]), inertia=bool(m["inertia"]), mass=float(m["mass"]),
                delay=delay, nonnegative=tuple(m["nonnegative"]), names=dict(m["names"]),
                orders=tuple(None if o is None else int(o) for o in m["orders"]), others=others,
            )
            coefficients = {str(k): float(v) for k, v in data["coefficients"].items()}
            tau = None if data["tau"] is None else float(data["tau"])
            lam = float(data["lambda"])
        except CvxidError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise CvxidError(f"the model file is incomplete or corrupted ({type(exc).__name__}: {exc})") from None
        unknown = set(coefficients) - set(spec.column_names)
        if unknown:
            raise CvxidError(f"the model file has coefficients for unknown columns: {', '.join(sorted(unknown))}")
        if not all(np.isfinite(v) for v in coefficients.values()):
            raise CvxidError("the model file has non-finite coefficients")
        return cls(spec, coefficients, lam, tau=tau)

    def save(self, path) -> None:
        """Write the model as JSON (never pickle)."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2))

    @classmethod
    def load(cls, path) -> "IdentifiedModel":
        """Read a model written by :meth:`save`."""
        try:
            data = json.loads(Path(path).read_text())
        except FileNotFoundError:
            raise CvxidError(f"model file not found: {path}") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise CvxidError(f"{path}: not a JSON model file ({exc})") from None
        if not isinstance(data, dict):
            raise CvxidError(f"{path}: not a JSON model file (a {type(data).__name__} at the top level)")
        return cls.from_dict(data)

    # ------------------------------------------------------------------ python-control
    def to_control(self, pade_order: int = 6):
        """The model as a python-control ``NonlinearIOSystem`` (input f, output x), with
        the delay as a Padé approximation of ``pade_order``."""
        from cvxid.export import to_nlsys

        return to_nlsys(self, pade_order)

    def linearized_tf(self, pade_order: int = 6):
        """The linearisation at rest as a python-control transfer function f -> x, the
        delay as a Padé approximation (for margins and controller design)."""
        from cvxid.export import linearized_tf

        return linearized_tf(self, pade_order)
