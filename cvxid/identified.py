r"""The result of an identification: :class:`IdentifiedSystem` of
:class:`IdentifiedModel` equations.

An :class:`IdentifiedModel` is one identified equation: the regression coefficients, the
physical parameters they map to, the selected support; it prints its equation, simulates
itself and tabulates itself.  An :class:`IdentifiedSystem` holds :math:`N \ge 1` of them
with the shared delay and the ties; it simulates every coordinate at once and is written
to JSON in one schema (``cvxid.system/1``) whatever :math:`N` (files of the earlier
``cvxid.identified/1`` and ``cvxid.joint/1`` schemas still load).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from cvxid.data.experiment import Experiment
from cvxid.initial_state import free_run
from cvxid.errors import CvxidError
from cvxid.metrics import fit_percent, measurement_noise, noise_ceiling_percent, relative_error_percent
from cvxid.model.equation import ModelSpec
from cvxid.model.system import SystemSpec
from cvxid.model.terms import latex_symbol
from cvxid.regression.history import padded, simulation_start, start_index
from cvxid.regression.velocity import initial_state
from cvxid.simulate import (
    CoupledSystem,
    Equation,
    SimulationDiverged,
    System,
    simulate,
    simulate_coupled,
    substeps_for,
)

SCHEMA = "cvxid.identified/1"
"""One equation's own format (also the format of each equation inside a system file)."""
SYSTEM_SCHEMA = "cvxid.system/1"


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
        gain = (*(gain or (0.0,)), 0.0)  # (the signal's, its rate's)
        return System(
            terms=tuple(lib),
            coefficients=np.array([terms[t.name] for t in lib]),
            mass=mass,
            coordinate=self.spec.coordinate,
            gain=gain[0],
            tau=tau or 0.0,
            derivative=delay.derivative if delay else 0,
            history=history,
            rate_gain=gain[1],
        )

    def equation(self) -> str:
        """The identified equation in physical form, e.g.
        ``0.99 x'' + 1.06 x' + … = f + 2 x(t - 0.166)``."""
        text = self.system().equation().replace(" = f", f" = {self.spec.input_text()}", 1)
        delay = self.spec.delay
        if delay is not None and delay.coordinate != self.spec.coordinate:  # fed back from another coordinate
            for order, signal in zip(delay.orders, delay.signals):
                text = text.replace(f" {self.spec.coordinate}{chr(39) * order}(t - ", f" {signal}(t - ")
        return text

    def equation_latex(self) -> str:
        """The identified equation in LaTeX."""
        system = self.system()
        accel = latex_symbol(self.spec.coordinate + "''")
        lhs = f"{float(system.mass):.6g}\\,{accel}"
        for term, c in zip(system.terms, np.atleast_1d(system.coefficients)):
            lhs += f" {'-' if c < 0 else '+'} {abs(c):.6g}" + ("" if term.name == "1" else f"\\,{term.latex}")
        rhs = self.spec.input_text()
        if self.spec.delay is not None:
            for gain, signal in zip((system.gain, system.rate_gain), self.spec.delay.signals):
                if float(gain):
                    rhs += (f" {'-' if gain < 0 else '+'} {abs(float(gain)):.6g}\\,{latex_symbol(signal)}"
                            f"(t - {float(system.tau):.6g})")
        return f"{lhs} = {rhs}"

    def regression_equation(self) -> str:
        """The identified regression, column by column (delay terms unresolved)."""
        parts = [f"{c:+.6g} {n}" for n, c in self.coefficients.items() if c != 0.0]
        return " ".join(parts) + f" = {self.spec.input_text()}"

    def simulate(self, experiment: Experiment, x0: float | None = None, v0: float | None = None,
                 history: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Free-run simulation under the experiment's measured input, from the state
        ``(x0, v0)`` at its start (by default the record's smoothed state there,
        :meth:`initial_state`; :func:`cvxid.compare` fits the start to the whole record
        instead, and its ``initial_state`` passed here reproduces its free run).  With the measured
        history (:mod:`cvxid.regression.history`) it starts at :math:`t_0 + \\tau_{\\max}`
        (the first sample whose delayed past is measured), so ``(x0, v0)`` is the state
        there and the samples before are NaN; ``history="zero"`` or ``"initial"`` starts at
        :math:`t_0` with an assumed past."""
        if x0 is None or v0 is None:
            guess = self.initial_state(experiment, history)
            x0, v0 = guess[0] if x0 is None else x0, guess[1] if v0 is None else v0
        return self.simulator(experiment, history)(x0, v0)

    def simulator(self, experiment: Experiment, history: str | None = None):
        """:meth:`simulate` from any start ``(x0, v0)``, everything else (the system, the
        input, the measured past) prepared once: for searches over the start."""
        system = self.system(history)
        k, past = simulation_start(experiment, self.spec.delay, system.history)
        t, u = experiment.time[k:], self.spec.received_input(experiment)[k:]
        substeps = substeps_for(experiment.output(self.spec.coordinate)[k:], experiment.dt)

        def run(x0: float, v0: float) -> tuple[np.ndarray, np.ndarray]:
            x, v = simulate(system, t, u, x0, v0, substeps=substeps, past=past)
            return padded(x, k), padded(v, k)

        return run

    def initial_state(self, experiment: Experiment, history: str | None = None) -> tuple[float, float]:
        """The record's own state (position, velocity) where :meth:`simulate` starts,
        from a smoothing fit of the measured output there."""
        k = start_index(experiment, self.spec.delay, self.system(history).history)
        return initial_state(experiment.time[k:], experiment.output(self.spec.coordinate)[k:])

    def table(self, truth: dict[str, float] | None = None) -> pd.DataFrame:
        """Physical parameters, beside the truth when it is known: the model's own, and
        those of the truth it set to 0 (the candidates a selection dropped are left out: 12
        rows of "0 NaN" in 17 of a selected library; :attr:`coefficients` holds them).  A
        parameter the truth lacks is 0 in it (it was NaN: a seventh outside check)."""
        phys = {k: v for k, v in self.physical.items() if v != 0 or k in (truth or {})}
        frame = pd.DataFrame({"estimate": pd.Series(phys, dtype=float)})
        if truth:
            frame["truth"] = pd.Series({k: truth.get(k, 0.0) for k in phys}, dtype=float)
            frame["error %"] = relative_error_percent(frame["estimate"], frame["truth"])
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
                    "coordinate": delay.coordinate, "derivative": delay.derivative,
                    "gain": list(delay.gain) if delay.rate and delay.gain is not None else delay.gain,
                    "taylor_order": delay.taylor_order, "method": delay.method, "tau_min": delay.tau_min,
                    "tau_max": delay.tau_max, "history": delay.history, "rate": delay.rate,
                },
                "nonnegative": list(spec.nonnegative),
                "names": dict(spec.names),
                "orders": list(spec.orders),
                "input_delay": None if spec.input_delay is None else spec.input_delay.as_dict(),
                "listed": list(spec.listed),
                "keep_linear": spec.keep_linear,
            },
            "coefficients": {k: float(v) for k, v in self.coefficients.items()},
            "lambda": float(self.lam),
            "tau": None if self.tau is None else float(self.tau),
        }

    @classmethod
    def from_dict(cls, data: dict) -> "IdentifiedModel":
        """Rebuild a model written by :meth:`to_dict`, checking every field."""
        from cvxid.model.delay import DelayedFeedback
        from cvxid.model.input_delay import InputDelay
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
                gain = tuple(d["gain"]) if isinstance(d["gain"], list) else d["gain"]
                delay = DelayedFeedback(str(d.get("coordinate", coord)), int(d["derivative"]), gain,
                                        int(d["taylor_order"]), str(d["method"]), float(d["tau_max"]),
                                        float(d["tau_min"]), str(d["history"]), bool(d.get("rate", False)))
            spec = ModelSpec(
                library=Library(parse_term(n, (coord, *others)) for n in m["library"]),
                coordinate=coord, input=str(m["input"]), inertia=bool(m["inertia"]), mass=float(m["mass"]),
                delay=delay, nonnegative=tuple(m["nonnegative"]), names=dict(m["names"]),
                orders=tuple(None if o is None else int(o) for o in m["orders"]), others=others,
                input_delay=None if m.get("input_delay") is None else InputDelay.from_dict(m["input_delay"]),
                # (files written before these keys: every term a candidate, as then)
                listed=tuple(str(n) for n in m.get("listed", ())), keep_linear=bool(m.get("keep_linear", False)),
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
        """Write the model as JSON (never pickle), as a system of one equation."""
        IdentifiedSystem.of(self).save(path)

    @classmethod
    def load(cls, path) -> "IdentifiedModel":
        """Read a one-equation model file (written by :meth:`save` or by
        :meth:`IdentifiedSystem.save`)."""
        system = IdentifiedSystem.load(path)
        if system.single is None:
            raise CvxidError(f"{path} holds {len(system.models)} coupled equations: read it with IdentifiedSystem.load")
        return system.single

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


# ---------------------------------------------------------------------- systems
@dataclass(frozen=True)
class IdentifiedSystem:
    """Identified equations by label (their coordinate), the shared delay, the delay
    profile ``(taus, values)`` when one was computed, the ties and the fit's figures."""

    models: dict[str, IdentifiedModel]
    tau: float | None = None
    profile: tuple[np.ndarray, np.ndarray] | None = None
    ties: tuple[tuple[str, str, float], ...] = ()
    info: dict = field(default_factory=dict)

    @classmethod
    def of(cls, model: "IdentifiedModel | IdentifiedSystem") -> "IdentifiedSystem":
        """The system of one identified equation (a system is itself)."""
        if isinstance(model, IdentifiedSystem):
            return model
        if not isinstance(model, IdentifiedModel):
            raise CvxidError(f"an identified model is needed (a run's result.model, IdentifiedModel.load(path)), got "
                             f"{type(model).__name__}")
        return cls({model.spec.coordinate: model}, model.tau, info=dict(model.info))

    @property
    def single(self) -> IdentifiedModel | None:
        """The model when there is one equation (``None`` for a coupled system)."""
        return next(iter(self.models.values())) if len(self.models) == 1 else None

    @property
    def specs(self) -> dict[str, ModelSpec]:
        return {label: m.spec for label, m in self.models.items()}

    @property
    def spec(self) -> SystemSpec:
        """The system that was identified: its equations' specs and the ties."""
        return SystemSpec(self.specs, self.ties)

    @property
    def coordinates(self) -> list[str]:
        return [m.spec.coordinate for m in self.models.values()]

    def column(self, label: str, name: str) -> str:
        """A column's name: bare for one equation, ``"label:name"`` for several."""
        return name if len(self.models) == 1 else f"{label}:{name}"

    @property
    def coefficients(self) -> dict[str, float]:
        """Every regression coefficient by column name."""
        return {self.column(label, n): c for label, m in self.models.items() for n, c in m.coefficients.items()}

    @property
    def physical(self) -> dict[str, float]:
        """Physical parameters: one equation's own names (``m``, ``k``, ``tau``); in a
        coupled system see :func:`system_physical`."""
        if self.single is not None:
            return self.single.physical
        return system_physical(self.specs, {label: m.coefficients for label, m in self.models.items()}, self.tau)

    def equations(self) -> list[str]:
        return [m.equation() for m in self.models.values()]

    # ------------------------------------------------------------------ simulation
    def system(self) -> CoupledSystem:
        """The identified system, ready to simulate (each equation's input with gain 1)."""
        equations, delayed, tau, history, derivative = [], None, 0.0, "zero", 0
        for model in self.models.values():
            s = model.system()
            equations.append(Equation(model.spec.coordinate, float(s.mass), s.terms,
                                      tuple(np.atleast_1d(s.coefficients)), 1.0, float(s.gain), float(s.rate_gain)))
            if model.spec.delay is not None:
                delayed, tau, history = model.spec.delay.coordinate, float(s.tau), s.history
                derivative = model.spec.delay.derivative
        return CoupledSystem(tuple(equations), delayed or equations[0].coordinate, tau, history, derivative)

    def simulate(self, experiment: Experiment, initial: dict | None = None) -> dict[str, np.ndarray]:
        """Free-run simulation of every coordinate under ``experiment``'s inputs, from
        ``initial`` (coordinate → (position, velocity)) or the state estimated from the data."""
        return self.simulator(experiment)(initial or self.initial_state(experiment))

    def simulator(self, experiment: Experiment):
        """:meth:`simulate` from any start (coordinate → (position, velocity)), everything
        else prepared once: for searches over the start."""
        system, delay = self.system(), next(iter(self.specs.values())).delay
        k, past = simulation_start(experiment, delay, system.history if delay is not None else None)
        t = experiment.time[k:]
        inputs = [m.spec.received_input(experiment)[k:] for m in self.models.values()]
        substeps = max(substeps_for(experiment.output(c)[k:], experiment.dt) for c in self.coordinates)

        def run(initial: dict) -> dict[str, np.ndarray]:
            x, _ = simulate_coupled(system, t, inputs, {c: v[0] for c, v in initial.items()},
                                    {c: v[1] for c, v in initial.items()}, past=past, substeps=substeps)
            return {c: padded(values, k) for c, values in x.items()}

        return run

    def input_noise_spread(self, experiment: Experiment, state: dict, free: dict) -> dict[str, float]:
        """Each coordinate's RMS response to the noise on the measured inputs: the free run
        from ``state`` with white noise added at each read input's measurement-noise level
        (:func:`~cvxid.metrics.measurement_noise`), less ``free`` (coordinate → the run from
        ``state`` on the record as measured, aligned to the record's end).  The part of a
        perfect model's free-run error that the measured input's noise makes; 0 where no
        input carries such noise or the noisy run diverges.  Seeded."""
        read = {m.spec.input_column for m in self.models.values()} & set(experiment.inputs)
        levels = {name: measurement_noise(experiment.inputs[name]) for name in read}
        if not any(levels.values()):
            return {c: 0.0 for c in self.coordinates}
        rng = np.random.default_rng(0)
        noisy = replace(experiment, inputs={**experiment.inputs, **{
            name: experiment.inputs[name] + level * rng.standard_normal(experiment.n) for name, level in levels.items()}})
        try:
            again = self.simulator(noisy)(state)
        except SimulationDiverged:
            return {c: 0.0 for c in self.coordinates}
        spread = {}
        for c in self.coordinates:
            difference = again[c][again[c].size - free[c].size:] - free[c]
            spread[c] = float(np.sqrt(np.nanmean(difference**2))) if np.isfinite(difference).any() else 0.0
        return spread

    def initial_state(self, experiment: Experiment) -> dict[str, tuple[float, float]]:
        """Every coordinate's own state where :meth:`simulate` starts, from a smoothing fit."""
        delay = next(iter(self.specs.values())).delay
        k = start_index(experiment, delay, self.system().history) if delay is not None else 0
        return {c: initial_state(experiment.time[k:], experiment.output(c)[k:]) for c in self.coordinates}

    def compare(self, experiment: Experiment, initial: str = "estimated") -> pd.DataFrame:
        """Free-run fit (%) and RMS error of every coordinate on ``experiment``, and the
        start the free run used (``initial_position``, ``initial_velocity``): the state
        ``initial`` names, ``"estimated"`` (least squares over the record, with the fit
        from the record's own start beside it as ``record_fit_percent``) or ``"record"``.
        A diverging simulation gives fit -inf."""
        run, measured = self.simulator(experiment), {c: experiment.output(c) for c in self.coordinates}
        state, record = self.initial_state(experiment), None
        try:
            state, sim, own = free_run(run, measured, state, initial)
            if own is not None:
                record = {c: fit_percent(measured[c], own[c]) for c in self.coordinates}
        except SimulationDiverged:
            sim = None
        driven = {} if sim is None else self.input_noise_spread(experiment, state, sim)
        rows = []
        for c in self.coordinates:
            y = measured[c]
            row = {"coordinate": c, "fit_percent": -np.inf, "rms": np.inf}
            if sim is not None:
                row.update(fit_percent=fit_percent(y, sim[c]), rms=float(np.sqrt(np.nanmean((sim[c] - y) ** 2))))
            if initial == "estimated":
                row["record_fit_percent"] = -np.inf if record is None else record[c]
            row.update(initial_position=state[c][0], initial_velocity=state[c][1],
                       noise_ceiling_percent=noise_ceiling_percent(y, driven.get(c, 0.0)))
            rows.append(row)
        return pd.DataFrame(rows).set_index("coordinate")

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict:
        """A JSON-ready description (schema ``cvxid.system/1``): every equation's model,
        the delay and the ties."""
        return {"schema": SYSTEM_SCHEMA, "tau": None if self.tau is None else float(self.tau),
                "ties": [{"left": a, "right": b, "factor": float(f)} for a, b, f in self.ties],
                "equations": {label: m.to_dict() for label, m in self.models.items()}}

    @classmethod
    def from_dict(cls, data: dict) -> "IdentifiedSystem":
        """Rebuild a system written by :meth:`to_dict` (or a file of the earlier one-equation
        ``cvxid.identified/1`` or coupled ``cvxid.joint/1`` schema), checking every field."""
        schema = data.get("schema")
        if schema == SCHEMA:
            return cls.of(IdentifiedModel.from_dict(data))
        if schema not in (SYSTEM_SCHEMA, "cvxid.joint/1"):
            raise CvxidError(f"not a cvxid model file (schema {schema!r}, expected {SYSTEM_SCHEMA!r}); write it "
                             "again with IdentifiedSystem.save")
        try:
            tau = None if data["tau"] is None else float(data["tau"])
            ties = tuple((str(t["left"]), str(t["right"]), float(t["factor"])) for t in data["ties"])
            models = {str(k): IdentifiedModel.from_dict(v) for k, v in data["equations"].items()}
        except CvxidError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise CvxidError(f"the model file is incomplete or corrupted ({type(exc).__name__}: {exc})") from None
        if not models:
            raise CvxidError("the model file has no equations")
        if tau is not None and (not np.isfinite(tau) or any(m.tau not in (None, tau) for m in models.values())):
            raise CvxidError("the model file's delay is not finite or differs between its equations")
        system = cls(models, tau, ties=ties)
        names = set(system.coefficients)
        for a, b, factor in ties:
            for name in (a, b):
                if name not in names:
                    raise CvxidError(f"the model file's tie {a!r} = {factor:g} {b!r} names an unknown column {name!r}")
        return system

    def save(self, path) -> None:
        """Write the system as JSON (never pickle)."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2))

    @classmethod
    def load(cls, path) -> "IdentifiedSystem":
        """Read a model file (``cvxid.system/1``, or the earlier schemas)."""
        try:
            data = json.loads(Path(path).read_text())
        except FileNotFoundError:
            raise CvxidError(f"model file not found: {path}") from None
        except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise CvxidError(f"{path}: not a JSON model file ({exc})") from None
        if not isinstance(data, dict):
            raise CvxidError(f"{path}: not a JSON model file (a {type(data).__name__} at the top level)")
        return cls.from_dict(data)

    def __repr__(self) -> str:
        if self.single is not None:
            return repr(self.single)
        tau = "" if self.tau is None else f": tau = {self.tau:.5g}"
        lines = [f"IdentifiedSystem of {len(self.models)} equations{tau}"]
        lines += [f"  {e}" for e in self.equations()]
        if self.ties:
            lines.append("  ties: " + ", ".join(f"{a} = {f:g} {b}" for a, b, f in self.ties))
        return "\n".join(lines)


def system_physical(specs: dict[str, ModelSpec], coefficients: dict[str, dict[str, float]], tau: float | None,
                    extra_terms: dict[str, dict[str, float]] | None = None) -> dict[str, float]:
    """Physical parameters of every equation of a coupled system: a name from
    ``[model.equation.names]`` where one is given (``"-alpha"`` is minus the coefficient),
    else ``"coordinate:term"``; the inertia ``"coordinate:m"``; the delay ``tau``."""
    out = {}
    for coord, spec in specs.items():
        mass, terms, _, gain = spec.physical_terms(coefficients[coord], tau)
        terms = dict(terms, **(extra_terms or {}).get(coord, {}))
        values = {spec.inertia_term.name: mass, **terms}
        for term, value in values.items():
            pname, sign = spec.named_parameter(term)
            if pname == term:
                pname = f"{coord}:m" if term == spec.inertia_term.name else f"{coord}:{term}"
            out[pname] = sign * value
        if spec.delay is not None:
            out.update({f"{coord}:{name}": value for name, value, free in zip(spec.gain_names, gain, spec.delay.estimated)
                        if free})
    if tau is not None:
        out["tau"] = tau
    late = next(iter(specs.values())).input_delay  # (shared by every equation)
    if late is not None:
        out["tau_u"] = late.value
    return out
