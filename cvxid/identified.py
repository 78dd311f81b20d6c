"""The result of an identification: :class:`IdentifiedModel`.

It holds the regression coefficients, the physical parameters they map to, the selected
support, and can print its equation, simulate itself and tabulate itself.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .data import Experiment
from .model import ModelSpec
from .simulate import System, simulate


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
        return self.system().equation().replace(" = f", f" = {self.spec.input}", 1)

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
