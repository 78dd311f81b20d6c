r"""``cvxid bench --heldout``: seeded random delayed oscillators that cvxid's examples do not contain.

Each seed draws one system

.. math::

    m\,\ddot x + c\,\dot x + k_1 x + k_3 x^3 + [\text{hidden effect}] = f(t) + b\,x(t-\tau)

(:func:`draw`), simulates a training and a test record of it that start in mid-motion,
writes them as CSV files with a TOML spec beside them (:func:`write`) and identifies it
exactly as ``cvxid run`` does (:func:`cvxid.app.run.run` on the spec file, read back
through ``result.to_dict()``, the content of ``result.json``).  :func:`heldout` runs many
systems and tabulates the errors; :func:`summary` groups them by effect and noise;
:func:`by_duration` pairs the same systems recorded for different lengths.

Seeds 0–99 are the TUNING range: look at them while changing cvxid.  Seeds 1000 and up are
the REPORT range: quote their numbers, never tune on them.

The draw (all uniform unless said):

* mass in [0.5, 2], stiffness ``k1`` in [2, 20], damping ``c`` in [0.1, 1] (relative
  damping ``c / (2 sqrt(k1 m))`` 0.008 to 0.5), cubic stiffness ``k3`` 0 (one system in
  three) or in [0, 3];
* the delayed feedback ``+ b x(t - tau)``: ``|b|`` in [0.3, 0.5] ``k1`` with a random sign,
  ``tau`` in :data:`TAU_RANGE`; with ``feedback = "paper"`` the paper's form
  ``+ b x(t - tau) + b1 x'(t - tau)``, ``|b1|`` in :data:`RATE_SHARE` times ``c`` with a
  random sign (from its own stream: the rest of the draw is the seed's);
* the hidden effect (``coulomb``, ``quadratic_damping``, ``quadratic_stiffness``,
  ``offset`` or none): a force of :data:`EFFECT_SHARE` of the force scale ``k1 x_rms``;
  or ``input_delay``: the system receives ``f(t - tau_u)``, ``tau_u`` in
  :data:`INPUT_DELAY_RANGE` (drawn from its own stream, so the rest of the draw is the
  seed's whatever the effect); or ``stribeck``: a Coulomb friction of that force plus as
  much again that decays with the speed, ``F (1 + exp(-(x'/v_s)^2)) sign(x')``
  (:data:`STRIBECK_SPEED`; the diagnosis-mode spec declares the Stribeck term with the true
  ``v_s`` as its own effect, as a user who knows the drive would);
* each record's forcing: a multisine (3–6 sines, frequencies log-uniform over
  :data:`BAND` times ``sqrt(k1/m)``, random phases and weights) or a linear chirp over that
  band (cvxid's ``quadratic_chirp``, shifted in time), scaled so that the standard
  deviation of x is a target drawn in [0.3, 1];
* the record length log-uniform in [5, 200] s (the test record is as long, at most
  :data:`TEST_DURATION`), ``dt`` = :data:`DT`, white noise of one standard deviation on x
  and f drawn from :data:`NOISES`.

Every record starts in mid-motion: the truth is simulated (cvxid's RK4, :data:`SUBSTEPS`
steps per sample) from rest at ``t = -pre`` with ``pre`` in [2, 5] s and only ``t >= 0`` is
kept, so ``x(0)``, ``x'(0)`` and the delayed feedback before ``t = 0`` are real.  A draw is
rejected, and the seed's next attempt drawn, when the unforced response from ``x = x_rms``
does not decay (its peak-to-peak swing over the last :data:`DECAY_WINDOW` s of
:data:`DECAY_SECONDS` is more than half that over the first), when a record's simulation
diverges or when its x RMS leaves :data:`X_RMS`.  The parameters drawn for a seed do not
depend on the effect, noise or length asked for, except through that rejection.

The spec (mode ``"structure"``): the true terms as the library, the exact delay on x with
the documented default range ``[tau_min, tau_max] = [0, 0.5]`` (it contains
:data:`TAU_RANGE`), the gain estimated (given with ``known_gain``), ``x'' >= 0``, the
output-error polish, an input delay to estimate with its default bound when the system has
one, everything else the documented defaults.  Mode ``"diagnosis"``
starts from ``x, x', x^3`` without the hidden term and adds ``[diagnose] refine = true``.
Mode ``"selection"`` lists no term: the library is the order-3 polynomial in x and x' plus
:data:`SELECTION_EXTRA` (18 candidates), and the estimator (the documented default, or the
one asked for) must select the true ones.  Mode ``"selection_diagnosis"``: the order-3
polynomial alone (15 candidates; a hidden effect's term is not among them, except a
quadratic stiffness) with ``[diagnose] refine = true``: the selection, then the diagnosis,
must end on exactly the true terms.
"""

from __future__ import annotations

import json
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from joblib import Parallel, delayed

from cvxid.app.report import plain
from cvxid.app.run import run
from cvxid.data.excitation import excitation
from cvxid.data.experiment import Experiment
from cvxid.diagnosis.compare import compare_system, mean_fit
from cvxid.errors import CvxidError
from cvxid.identify.output_error import delay_standard_error
from cvxid.metrics import noise_multiple
from cvxid.model.library import Library, resolve_term
from cvxid.model.terms import parse_term
from cvxid.progress import progress
from cvxid.simulate import SimulationDiverged, System, simulate

TAU_RANGE = (0.05, 0.3)
EFFECTS = ("none", "coulomb", "quadratic_damping", "quadratic_stiffness", "offset", "input_delay", "stribeck")
STRIBECK_SPEED = 0.3
"""The Stribeck velocity of the ``stribeck`` effect, in units of the speed scale
``omega x_rms``: its breakaway force (twice the Coulomb level) decays as
``exp(-(x'/v_s)^2)``."""
OUTSIDE = ("abs_stiffness", "smooth_friction")
r"""Hidden effects outside the diagnosis's catalogue, drawn only when asked for by name (the
default list is :data:`EFFECTS`): a stiffness :math:`k_a\,x|x|` of either sign (a spring
that hardens or softens with the square of the stretch, as a gas spring or a magnetic
bearing), and a friction :math:`F \tanh(\dot x / v_t)` that turns over smoothly at
:data:`SMOOTH_SPEED` (a lubricated contact, the flexible joint's friction), each a force of
:data:`EFFECT_SHARE`.  The catalogue holds neighbours of both (:math:`x^2`, :math:`x^3`;
Coulomb and viscous friction), which fit part of them: what the run says of the rest is
what they measure (``examples/incomplete_models.py``)."""
SMOOTH_SPEED = 0.3
"""The ``smooth_friction`` effect's velocity scale :math:`v_t`, in units of the speed scale
``omega x_rms``."""
INPUT_DELAY_RANGE = (0.01, 0.05)
"""The input's delay ``tau_u`` (seconds) of the ``input_delay`` effect."""
FEEDBACKS = ("position", "paper")
"""What the drawn loop feeds back: the position, ``b x(t - tau)``, or the paper's position
and velocity, ``b x(t - tau) + b1 x'(t - tau)``."""
RATE_SHARE = (0.3, 0.7)
"""The fed-back velocity's gain ``|b1|`` (feedback ``"paper"``) as a share of the damping
``c``: a velocity feedback of the damping's size that leaves the loop stable."""
EFFECT_SHARE = (0.1, 0.3)
"""The hidden effect's force as a share of the force scale ``k1 x_rms``."""
NOISES = (0.001, 0.01, 0.02)
BAND = (0.3, 2.5)
"""Forcing frequencies, in units of the natural frequency ``sqrt(k1/m)``."""
DT = 1e-3
SUBSTEPS = 4
TEST_DURATION = 20.0
X_RMS = (0.15, 2.0)
TOLERANCE, SCALINGS = 0.15, 8
"""The forcing is scaled until the standard deviation of x is within ``TOLERANCE`` (relative)
of its target, in at most ``SCALINGS`` simulations."""
DECAY_SECONDS, DECAY_WINDOW = 30.0, 5.0
ATTEMPTS = 50
BASE_TERMS = ("x", "x'", "x^3")
MODES = ("structure", "diagnosis", "selection", "selection_diagnosis")
SELECTION_EXTRA = ("coulomb", "quadratic_damping", "offset")
"""Selection mode's library beyond the order-3 polynomial in x and x' (which holds the
quadratic stiffness): the catalogue effects a hidden effect may be, the same for every
system, so the true terms of :data:`SELECTION_EFFECTS` are always candidates and never
singled out.  (A Stribeck friction's decay and a late input are not terms of this library:
the selection modes leave those effects out by default.)"""
SELECTION_EFFECTS = ("none", "coulomb", "quadratic_damping", "quadratic_stiffness", "offset")


@dataclass(frozen=True)
class Forcing:
    """One record's input: cvxid excitation components evaluated at ``t + shift``, and the
    seconds ``pre`` simulated before the record starts (``t = -pre``)."""

    kind: str  # "multisine" or "chirp"
    components: tuple[dict, ...]
    shift: float
    pre: float

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return excitation(self.components)(np.asarray(t, float) + self.shift)

    def scaled(self, factor: float) -> Forcing:
        parts = tuple(dict(c, amplitude=c["amplitude"] * factor) for c in self.components)
        return Forcing(self.kind, parts, self.shift, self.pre)


@dataclass(frozen=True)
class Oscillator:
    """A drawn system: ``mass x'' + sum coefficients = f + gain x(t - tau)``, its records'
    forcings, noise and length."""

    seed: int
    effect: str
    mass: float
    coefficients: tuple[tuple[str, float], ...]  # (term name, value), left-hand side, non-zero only
    gain: float
    tau: float
    noise: float
    duration: float
    train: Forcing
    test: Forcing
    attempt: int
    input_tau: float = 0.0  # the input's delay (the input_delay effect)
    rate_gain: float = 0.0  # the fed-back velocity's gain (feedback "paper")

    @property
    def terms(self) -> list[str]:
        return [name for name, _ in self.coefficients]

    @property
    def truth(self) -> dict[str, float]:
        """Physical parameters as a run names them (``m``, term names, ``tau``, ``gain``,
        ``tau_u`` for a late input)."""
        late = {"tau_u": self.input_tau} if self.input_tau else {}
        rate = {"rate_gain": self.rate_gain} if self.rate_gain else {}
        return {"m": self.mass, **dict(self.coefficients), "tau": self.tau, "gain": self.gain, **rate, **late}

    @property
    def system(self) -> System:
        return _system(self.mass, self.coefficients, self.gain, self.tau, self.rate_gain)

    def simulate(self, which: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Noise-free time (from 0), x, x' and f of the ``"train"`` or ``"test"`` record."""
        forcing = self.train if which == "train" else self.test
        length = self.duration if which == "train" else min(self.duration, TEST_DURATION)
        return _record(self.system, forcing, length, self.input_tau)

    def experiment(self, which: str) -> Experiment:
        """The measured record: x and f with white noise (seeded by the seed, attempt and record)."""
        t, x, _, f = self.simulate(which)
        rng = np.random.default_rng([self.seed, self.attempt, 1 if which == "train" else 2])
        return Experiment(t, {"x": x + self.noise * rng.standard_normal(t.size)},
                          {"f": f + self.noise * rng.standard_normal(t.size)}, name=which)


def _system(mass: float, coefficients: tuple[tuple[str, float], ...], gain: float, tau: float,
            rate_gain: float = 0.0) -> System:
    return System(tuple(parse_term(n) for n, _ in coefficients), np.array([v for _, v in coefficients]), mass,
                  gain=gain, tau=tau, rate_gain=rate_gain)


def _record(system: System, forcing: Forcing, duration: float, input_tau: float = 0.0):
    """Time from 0, x, x' and the forcing as recorded; the system receives it ``input_tau`` late."""
    skip = round(forcing.pre / DT)
    n = skip + round(duration / DT) + 1
    t = (np.arange(n) - skip) * DT
    x, v = simulate(system, t, lambda s: forcing(s - input_tau), 0.0, 0.0, substeps=SUBSTEPS)
    return np.arange(n - skip) * DT, x[skip:], v[skip:], forcing(t[skip:])


def draw(seed: int, effect: str | None = None, noise: float | None = None,
         duration: float | None = None, feedback: str = "position") -> Oscillator:
    """The seed's system with the hidden ``effect`` (None or ``"none"``: no hidden effect),
    its noise level and record length drawn unless given, its position fed back (``feedback
    = "paper"``: its velocity too; see the module docstring)."""
    effect = "none" if effect is None else effect
    if effect not in EFFECTS + OUTSIDE:
        raise CvxidError(f"unknown hidden effect '{effect}'; one of: {', '.join(EFFECTS + OUTSIDE)}")
    if feedback not in FEEDBACKS:
        raise CvxidError(f"unknown feedback '{feedback}'; one of: {', '.join(FEEDBACKS)}")
    for attempt in range(ATTEMPTS):
        oscillator = _attempt(seed, attempt, effect, noise, duration, feedback)
        if oscillator is not None:
            return oscillator
    raise CvxidError(f"seed {seed}: no stable system with effect '{effect}' in {ATTEMPTS} attempts")


def _attempt(seed: int, attempt: int, effect: str, noise: float | None, duration: float | None,
             feedback: str = "position"):
    rng = np.random.default_rng([seed, attempt])
    mass, k1, c = rng.uniform(0.5, 2.0), rng.uniform(2.0, 20.0), rng.uniform(0.1, 1.0)
    k3 = rng.uniform(0.0, 3.0) if rng.uniform() > 1 / 3 else 0.0
    gain = rng.choice((-1.0, 1.0)) * rng.uniform(0.3, 0.5) * k1
    tau = rng.uniform(*TAU_RANGE)
    target = rng.uniform(0.3, 1.0)
    share, sign = rng.uniform(*EFFECT_SHARE), rng.choice((-1.0, 1.0))
    drawn_noise = rng.choice(NOISES)
    drawn_duration = float(np.exp(rng.uniform(np.log(5.0), np.log(200.0))))
    noise = float(drawn_noise if noise is None else noise)
    duration = float(drawn_duration if duration is None else duration)
    omega = np.sqrt(k1 / mass)
    coefficients = {"x'": c, "x": k1, "x^3": k3}
    input_tau = float(np.random.default_rng([seed, attempt, 3]).uniform(*INPUT_DELAY_RANGE)) \
        if effect == "input_delay" else 0.0
    rate_gain = 0.0
    if feedback == "paper":
        own = np.random.default_rng([seed, attempt, 4])
        rate_gain = float(own.choice((-1.0, 1.0)) * own.uniform(*RATE_SHARE) * c)
    force, speed = share * k1 * target, omega * target  # (the hidden effect's force and speed scales)
    if effect == "stribeck":
        coefficients["sign(x')"] = force
        coefficients[_stribeck(STRIBECK_SPEED * speed)] = force
    elif effect in OUTSIDE:
        if effect == "abs_stiffness":
            coefficients[parse_term("x * abs(x)").name] = sign * force / target**2
        else:
            coefficients[parse_term(f"tanh(x' / {SMOOTH_SPEED * speed:.6g})").name] = force
    elif effect not in ("none", "input_delay"):
        size = {"coulomb": force, "quadratic_damping": force / speed**2, "quadratic_stiffness": sign * force / target**2,
                "offset": sign * force}[effect]
        coefficients[resolve_term(effect).name] = size
    coefficients = tuple((n, float(v)) for n, v in coefficients.items() if v != 0.0)
    system = _system(mass, coefficients, gain, tau, rate_gain)
    if not _decays(system, target):
        return None
    forcings = []
    for length in (duration, min(duration, TEST_DURATION)):
        forcing = _scaled(system, _forcing(rng, omega, length), length, target, k1 * target, input_tau)
        if forcing is None:
            return None
        forcings.append(forcing)
    return Oscillator(seed, effect, float(mass), coefficients, float(gain), float(tau), noise, duration, *forcings,
                      attempt, input_tau, rate_gain)


def _stribeck(speed: float) -> str:
    """The Stribeck term with the Stribeck velocity ``speed`` (its name as cvxid writes it)."""
    return parse_term(f"sign(x') * exp(-(x' / {speed:.6g})^2)").name


def _decays(system: System, amplitude: float) -> bool:
    """The unforced response from ``x = amplitude`` swings less at the end than half as much
    as at the start."""
    t = np.arange(0.0, DECAY_SECONDS, 0.01)
    try:
        x, _ = simulate(system, t, np.zeros_like(t), amplitude, 0.0, substeps=SUBSTEPS)
    except SimulationDiverged:
        return False
    window = int(DECAY_WINDOW / 0.01)
    return bool(np.ptp(x[-window:]) < 0.5 * np.ptp(x[:window]))


def _forcing(rng: np.random.Generator, omega: float, duration: float) -> Forcing:
    """A multisine or linear chirp over :data:`BAND` times ``omega``, of unit weights."""
    pre = rng.uniform(2.0, 5.0)
    lo, hi = BAND[0] * omega, BAND[1] * omega
    if rng.uniform() < 0.5:
        count = int(rng.integers(3, 7))
        omegas = np.sort(np.exp(rng.uniform(np.log(lo), np.log(hi), count)))
        parts = tuple({"kind": "sine", "amplitude": float(a), "omega": float(w), "phase": float(p)}
                      for a, w, p in zip(rng.uniform(0.5, 1.0, count), omegas, rng.uniform(0, 2 * np.pi, count)))
        return Forcing("multisine", parts, 0.0, pre)
    # sin(rate s^2) sweeps 2 rate s: from lo at t = -pre to hi at t = duration, with s = t + shift
    rate = (hi - lo) / (2 * (pre + duration))
    return Forcing("chirp", ({"kind": "quadratic_chirp", "amplitude": 1.0, "rate": rate},), pre + lo / (2 * rate), pre)


def _scaled(system: System, forcing: Forcing, duration: float, target: float, force: float,
            input_tau: float = 0.0) -> Forcing | None:
    """``forcing`` scaled to a standard deviation of x within :data:`TOLERANCE` of
    ``target``: from an RMS of ``force``, then by the ratio of standard deviations, or by
    bisection once the target is bracketed (friction makes the response jump).  None when
    the record diverges, the target is not reached in :data:`SCALINGS` simulations or the x
    RMS leaves :data:`X_RMS`."""
    t = np.arange(0.0, duration, DT)
    scale, low, high = force / np.std(forcing(t)), 0.0, np.inf
    for _ in range(SCALINGS):
        try:
            x = _record(system, forcing.scaled(scale), duration, input_tau)[1]
            ratio = target / max(float(np.std(x)), 1e-12)
        except SimulationDiverged:
            ratio = 0.0  # far too strong
        if abs(ratio - 1) < TOLERANCE:
            return forcing.scaled(scale) if X_RMS[0] <= np.sqrt(np.mean(x**2)) <= X_RMS[1] else None
        low, high = (scale, high) if ratio > 1 else (low, scale)
        scale = np.sqrt(low * high) if low > 0 and np.isfinite(high) else scale * np.clip(ratio, 0.2, 5.0)
    return None


# ---------------------------------------------------------------------- files
def _toml(value) -> str:
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a TOML basic string
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_toml(k)} = {_toml(v)}" for k, v in value.items()) + " }"
    return repr(float(value))


def spec_text(oscillator: Oscillator, mode: str = "structure", known_gain: bool = False,
              fit: dict | None = None, gaps: tuple[str, ...] = ()) -> str:
    """The TOML spec of ``oscillator`` reading ``train.csv`` and ``test.csv`` beside it
    (``fit``: ``[fit]`` settings beside the polish, e.g. ``{"estimator": "lasso"}``; the
    documented defaults for the others; ``gaps``: the records loaded with ``gaps = true``)."""
    if mode not in MODES:
        raise CvxidError(f"mode must be one of {', '.join(MODES)}, got '{mode}'")
    o = oscillator
    library = {"order": 3, "extra": list(SELECTION_EXTRA)} if mode == "selection" else {"order": 3} \
        if mode == "selection_diagnosis" else {"terms": o.terms if mode == "structure" else list(BASE_TERMS)}
    signal, gain = (["x", "x'"], [o.gain, o.rate_gain]) if o.rate_gain else ("x", o.gain)
    delay = {"signal": signal, "method": "exact"} | ({"gain": gain} if known_gain else {})
    tables = {
        "truth": {"mass": o.mass, "coefficients": dict(o.coefficients),
                  "delay": {"signal": signal, "gain": gain, "tau": o.tau}},
        **{f"data.{which}": {"file": f"{which}.csv", "time": "t", "output": "x", "input": "f"}
           | ({"gaps": True} if which in gaps else {}) for which in ("train", "test")},
        "model.library": library,
        "model.delay": delay,
        "model.constraints": {"nonnegative": ["x''"]},
        **({"model.input_delay": {}} if o.input_tau and mode == "structure" else {}),
        "fit": {"refine": "output_error", **(fit or {})},
        **({"diagnose": {"refine": True}} if mode in ("diagnosis", "selection_diagnosis") else {}),
        **({"diagnose.effects": {"stribeck": next(n for n, _ in o.coefficients if "exp" in n)}}
           if mode == "diagnosis" and o.effect == "stribeck" else {}),
    }
    lines = [f"name = {_toml(f'heldout_{o.seed}_{o.effect}')}",
             f"description = {_toml(f'cvxid bench --heldout: seed {o.seed}, attempt {o.attempt}, {mode} mode')}"]
    for table, keys in tables.items():
        lines += ["", f"[{table}]"] + [f"{k} = {_toml(v)}" for k, v in keys.items()]
    return "\n".join(lines) + "\n"


def write(oscillator: Oscillator, folder, mode: str = "structure", known_gain: bool = False,
          fit: dict | None = None, change=None) -> Path:
    """Write ``train.csv``, ``test.csv`` (columns t, x, f) and ``spec.toml`` into ``folder``;
    the spec's path.  ``change(which, rows)``: the record's rows (samples × [t, x, f]) as
    written, changed in place (an experiment's rounding, dropouts, a reversed input); a
    record it leaves with NaN samples is loaded with ``gaps = true``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    gaps = []
    for which in ("train", "test"):
        e = oscillator.experiment(which)
        rows = np.column_stack([e.time, e.output("x"), e.input("f")])
        if change is not None:
            change(which, rows)
        if np.isnan(rows).any():
            gaps.append(which)
        np.savetxt(folder / f"{which}.csv", rows, fmt="%.10g", delimiter=",", header="t,x,f", comments="")
    path = folder / "spec.toml"
    path.write_text(spec_text(oscillator, mode, known_gain, fit, tuple(gaps)), encoding="utf-8")
    return path


# ---------------------------------------------------------------------- runs
LEADING = ["seed", "effect", "noise", "duration", "kind", "true tau", "tau", "tau error %", "low", "high", "covers"]
TRAILING = ["worst other %", "others covered %", "tau limit %", "tau error / limit", "tau_u error %", "tau_u covers", "seconds", "status", "error"]
DIAGNOSIS = ["first effect", "added", "added by simulation", "first added", "equation error fall",
             "free-run error fall", "start to final fall"]
GAPS = ["train gap", "test gap", "gap said"]
GAP_WORDS = ("part of the dynamics is not in the model", "part of the dynamics may be missing",
             "the model lacks part of the dynamics")
"""What the gap and drift warnings say of a final model that misses part of the dynamics
(:func:`_gaps`)."""
SELECTION = ["support recovered", "missed", "spurious"]


def _error(estimate: float, truth: float) -> float:
    return 100.0 * (estimate / truth - 1.0)


def result_row(result: dict, oscillator: Oscillator, known_gain: bool) -> dict:
    """The errors of one run's ``result.json`` content against the truth (a parameter the
    model lacks counts as 0)."""
    tau = result["tau"] or {}
    truth = {k: v for k, v in oscillator.truth.items()
             if k not in ("tau", "tau_u") and not (k in ("gain", "rate_gain") and known_gain)}
    errors = {f"err % {k}": _error(result["physical"].get(k, 0.0), v) for k, v in truth.items()}
    interval = tau.get("interval")
    bounds = (result.get("polish") or {}).get("intervals") or {}
    covered = [bounds[k][0] <= v <= bounds[k][1] for k, v in truth.items() if k in bounds]
    diagnosis = result.get("diagnosis") or {}
    late = {}
    if oscillator.input_tau:  # a model without an input delay has tau_u = 0: error -100 %
        bounds = (result.get("input_delay") or {}).get("interval")
        late = {"tau_u error %": _error(result["physical"].get("tau_u", 0.0), oscillator.input_tau),
                "tau_u covers": bool(bounds[0] <= oscillator.input_tau <= bounds[1]) if bounds else None}
    return {
        "tau": tau.get("estimate", np.nan),
        "tau error %": _error(tau.get("estimate", np.nan), oscillator.tau),
        "low": interval[0] if interval else np.nan,
        "high": interval[1] if interval else np.nan,
        "covers": bool(interval[0] <= oscillator.tau <= interval[1]) if interval else None,
        **errors,
        "worst other %": max(abs(v) for v in errors.values()),
        "others covered %": 100.0 * np.mean(covered) if covered else np.nan,
        **late,
        **_gaps(result),
        "seconds": result["seconds"],
        "first effect": (diagnosis.get("ranking") or [{}])[0].get("effect"),
        "added": ",".join(step["added"] for step in result.get("refinement") or []),
        "added by simulation": ",".join(step["added"] for step in (result.get("simulation_diagnosis") or {})
                                        .get("steps", []) if step["kept"]),
        **_falls(result, oscillator.effect),
    }


def _gaps(result: dict) -> dict:
    r"""How far the final model's free runs miss the training and test records, each in
    multiples of what the record's noise allows, :math:`(100 - \text{fit}) / (100 -
    \text{ceiling})` (NaN where a run diverged or the figures are missing), and whether a
    warning said part of the dynamics is missing (:data:`GAP_WORDS`)."""
    def gap(record: str) -> float:
        multiple = noise_multiple(result.get(f"{record}_fit_percent"), result.get(f"{record}_fit_percent_noise_ceiling"))
        return np.nan if multiple is None else multiple
    return {"train gap": gap("train"), "test gap": gap("test"),
            "gap said": any(words in w for w in result.get("warnings", []) for words in GAP_WORDS)}


def _delay_limit(out, oscillator: Oscillator) -> dict:
    """Structure mode (the model has the true terms): the standard error of the delay that
    the training record allows an output-error fit at the true delay
    (:func:`~cvxid.identify.output_error.delay_standard_error`), in % of the delay, and the
    delay's error in units of it (about standard normal for an efficient estimator)."""
    if out.polish is None or "tau" not in out.polish.parameters:
        return {}
    try:
        se = delay_standard_error(out.polish.system, out.train, oscillator.tau, out.polish.initial)
    except (CvxidError, SimulationDiverged):  # the run itself stands; only its limit is unknown
        return {"tau limit %": np.nan, "tau error / limit": np.nan}
    return {"tau limit %": 100.0 * se / oscillator.tau, "tau error / limit": (out.polish.parameters["tau"] - oscillator.tau) / se}


def _falls(result: dict, effect: str) -> dict:
    """The first effect either diagnosis stage added, and by what factor the test record's
    errors fell (before / after) at the step that added ``effect``: the equation error's
    MSE and the free run's RMS (from the fits, :math:`(100 - \\text{fit}_0) / (100 -
    \\text{fit}_1)`) when the equation-error stage added it, the free run's RMS alone when the
    simulation stage did; NaN when it was not added, infinite when the model before it
    diverged.  (The equation stage's free runs start from the record's first state, the
    simulation stage's from an estimated one.)"""
    steps = [{**s, "stage": "equation"} for s in result.get("refinement") or []]
    steps += [{**s, "stage": "simulation"} for s in (result.get("simulation_diagnosis") or {}).get("steps", [])
              if s["kept"]]
    step = next((s for s in steps if s["added"] == effect), None)
    equation = free_run = np.nan
    if step is not None and step["stage"] == "equation":
        equation = step["test_mse_before"] / step["test_mse_after"]
        if step["fit_after"] is not None:  # a model before that diverged: an infinite fall
            free_run = np.inf if step["fit_before"] is None else \
                (100.0 - step["fit_before"]) / max(100.0 - step["fit_after"], 1e-12)
    elif step is not None:
        free_run = step["test_rms_before"] / step["test_rms_after"]
    return {"first added": steps[0]["added"] if steps else None, "equation error fall": equation,
            "free-run error fall": free_run}


def _start_to_final(out) -> float:
    r"""The test free run's error of the model the diagnosis started from over the run's
    final model's (after the output-error polish, when the spec polishes), both from the
    initial state estimated on the test record as the run reports its fit:
    :math:`(100 - \text{fit}_0) / (100 - \text{fit})`, what a user sees the diagnosis do.
    The falls at a step compare the diagnosis's equation-error models from the record's
    first state, where a Coulomb friction's model can stick (report seed 1005: 87 → 79 %
    at the step; the final model 98.9 % from an estimated start, 81.7 % from the record's
    own).  NaN when nothing was added, infinite when the starting model diverged."""
    refinement, final = out.refinement, mean_fit(out.comparisons or {})
    if refinement is None or not refinement.steps or refinement.start is None or final is None:
        return np.nan
    start = mean_fit(compare_system(refinement.start, out.test))
    return np.inf if start is None else (100.0 - start) / max(100.0 - final, 1e-12)


def selection_library() -> list[str]:
    """Selection mode's candidate terms (see :data:`SELECTION_EXTRA`)."""
    return Library.polynomial(3).names + [resolve_term(e).name for e in SELECTION_EXTRA]


def _selected(result: dict, oscillator: Oscillator) -> dict:
    """Selection mode: whether the run kept exactly the true terms, and which it missed or
    added."""
    kept = {n for n in selection_library() if result["coefficients"].get(n, 0.0) != 0.0}
    true = set(oscillator.terms)
    return {"support recovered": kept == true, "missed": ",".join(sorted(true - kept)),
            "spurious": ",".join(sorted(kept - true))}


def identify_drawn(oscillator: Oscillator, folder=None, mode: str = "structure", known_gain: bool = False,
                   fit: dict | None = None):
    """``oscillator``'s records and spec written into ``folder`` (:func:`write`; a
    temporary one by default) and identified as ``cvxid run`` does: the
    :class:`~cvxid.app.result.RunResult`, its warnings in it and not shown."""
    with warnings.catch_warnings(), tempfile.TemporaryDirectory() as scratch:
        warnings.simplefilter("ignore")  # run() records cvxid's own warnings itself
        return run(write(oscillator, scratch if folder is None else folder, mode, known_gain, fit))


def run_one(seed: int, effect: str, noise: float | None = None, duration: float | None = None,
            mode: str = "structure", known_gain: bool = False, keep=None, fit: dict | None = None,
            feedback: str = "position") -> dict:
    """One system drawn, written and identified by :func:`cvxid.app.run.run`: its row of
    :func:`heldout`.  Never raises: a failure is a row with ``status = "failed"`` and the
    exception's type and message.  ``keep``: a folder that keeps each system's files and
    ``result.json``."""
    row = {"seed": seed, "effect": effect, "noise": noise, "duration": duration, "status": "ok", "error": ""}
    with warnings.catch_warnings(), tempfile.TemporaryDirectory() as scratch:
        warnings.simplefilter("ignore")  # (the draw's too)
        try:
            oscillator = draw(seed, effect, noise, duration, feedback)
            row.update({"noise": oscillator.noise, "duration": oscillator.duration, "kind": oscillator.train.kind,
                        "true tau": oscillator.tau})
            name = f"{seed}_{oscillator.effect}_{oscillator.noise:g}_{oscillator.duration:.4g}s"
            folder = Path(keep) / name if keep else Path(scratch)
            out = identify_drawn(oscillator, folder, mode, known_gain, fit)
            result = out.to_dict()
            if keep:
                (folder / "result.json").write_text(json.dumps(plain(result), indent=2), encoding="utf-8")
            row.update(result_row(result, oscillator, known_gain))
            if mode == "diagnosis":
                row["start to final fall"] = _start_to_final(out)
            if mode == "structure":
                row.update(_delay_limit(out, oscillator))
            if mode.startswith("selection"):
                row.update(_selected(result, oscillator))
        except Exception as exc:  # noqa: BLE001  (one system's failure is its row, not the benchmark's)
            row.update(status="failed", error=f"{type(exc).__name__}: {exc}")
    return row


def heldout(seeds, effects=EFFECTS, noises=(None,), duration: float | None = None, mode: str = "structure",
            n_jobs: int = 2, keep=None, known_gain: bool = False, fit: dict | None = None,
            feedback: str = "position") -> pd.DataFrame:
    """Every (seed, effect, noise) drawn and identified, ``n_jobs`` at a time (joblib); one
    row per system.  A noise or ``duration`` of None is drawn.

    Columns: seed, effect, noise, duration, kind (of the training forcing), true tau, tau,
    tau error %, the tau interval (low, high, covers), ``err % <parameter>`` for every
    physical parameter (``m``, term names, ``gain``), worst other %, in structure mode the
    delay limit (``tau limit %``, :func:`_delay_limit`) and ``tau error / limit``, seconds
    (of the run), status, error; in diagnosis mode also the first ranked effect, the effects added (by
    either stage), the first added and the error falls at its step (:func:`_falls`); in
    selection mode whether the true support was recovered, the terms missed and the spurious
    ones.  ``fit``: ``[fit]`` settings for every spec (see :func:`spec_text`); ``feedback``:
    ``"paper"`` draws the paper's feedback of the position and the velocity (:func:`draw`).
    """
    if mode not in MODES:
        raise CvxidError(f"mode must be one of {', '.join(MODES)}, got '{mode}'")
    cases = [(s, e, n) for s in seeds for e in effects for n in noises]
    jobs = (delayed(run_one)(s, e, n, duration, mode, known_gain, keep, fit, feedback) for s, e, n in cases)
    rows = list(progress(Parallel(n_jobs=n_jobs, return_as="generator")(jobs), desc="heldout", total=len(cases)))
    frame = pd.DataFrame(rows)
    middle = sorted(c for c in frame.columns if c.startswith("err % "))
    extra = {"diagnosis": DIAGNOSIS, "selection": SELECTION, "selection_diagnosis": SELECTION + DIAGNOSIS}.get(mode, [])
    return frame.reindex(columns=LEADING + middle + TRAILING + GAPS + extra)


def summary(frame: pd.DataFrame, by=("effect", "noise")) -> pd.DataFrame:
    """Per group: systems, failures, median and 90th percentile of |tau error| %, median
    worst other %, the share of tau intervals that cover the truth (%), the mean share of the
    other parameters' intervals that cover theirs (%; each system's share), in structure mode the
    median of the delay's limit (the standard error the data allow, % of the delay), the
    systems that have one and the share of their errors within 1.96 of it (95 % for an efficient, unbiased estimator), for a late
    input the median |tau_u error| % and its intervals' coverage, in selection mode the share
    of systems whose true support was recovered (%), and median seconds."""
    frame = frame.assign(failed=frame["status"] != "ok", abs_tau=frame["tau error %"].abs(),
                         covered=frame["covers"].astype(float), abs_tau_u=frame["tau_u error %"].abs(),
                         covered_u=frame["tau_u covers"].astype(float),
                         recovered=frame.get("support recovered", pd.Series(np.nan, frame.index)).astype(float),
                         within=(frame["tau error / limit"].abs() <= 1.96).astype(float)
                         .where(frame["tau error / limit"].notna()))
    ok = frame[~frame["failed"]].groupby(list(by), sort=False)
    late = {"|tau_u err| % median": ok["abs_tau_u"].median(), "tau_u covers %": 100 * ok["covered_u"].mean()} \
        if frame["abs_tau_u"].notna().any() else {}
    support = {"support recovered %": 100 * ok["recovered"].mean()} if "support recovered" in frame else {}
    limit = {"tau limit % median": ok["tau limit %"].median(), "with a limit": ok["within"].count(),
             "within 1.96 limits %": 100 * ok["within"].mean()} if frame["tau limit %"].notna().any() else {}
    return pd.DataFrame({
        "systems": frame.groupby(list(by), sort=False).size(),
        "failures": frame.groupby(list(by), sort=False)["failed"].sum(),
        "|tau err| % median": ok["abs_tau"].median(),
        "|tau err| % p90": ok["abs_tau"].quantile(0.9),
        "worst other % median": ok["worst other %"].median(),
        "covers %": 100 * ok["covered"].mean(),
        **({"others covered %": ok["others covered %"].mean()} if "others covered %" in frame else {}),
        **limit,
        **late,
        **support,
        "seconds median": ok["seconds"].median(),
    })


PARTS = {"stribeck": ("coulomb",)}
"""Catalogue effects that are part of a hidden effect (a Stribeck friction has a Coulomb
level): adding them is not a wrong addition."""


def confusion(frame: pd.DataFrame, by=("effect",)) -> pd.DataFrame:
    """Diagnosis mode, per hidden effect: how often the diagnosis ranked it first (by the
    test equation error; collinear rivals by the test free run), how often it was added (by
    either stage, and by the simulation stage alone), how often it was the first effect
    added, the median factors by which its addition lowered the test record's equation error
    (MSE) and free-run error (RMS) at its step, the median and least factors of the free-run
    error from the starting model to the final one (:func:`_start_to_final`), how often
    another effect was added (a wrong addition; not one of its :data:`PARTS`), how often a
    warning said the final model misses part of the dynamics and the median of its training
    record's gap (:func:`_gaps`), and which effect was ranked first most often in its place.
    The control (``none``) can only have wrong additions.  ``by``: the grouping, the hidden
    effect first (``("effect", "noise")``: per noise level too)."""
    ok = frame[frame["status"] == "ok"]
    rows = {}
    for key, group in ok.groupby(list(by), sort=False):
        effect = key[0]
        added = [set(filter(None, f"{a},{s}".split(","))) for a, s in
                 zip(group["added"].fillna(""), group["added by simulation"].fillna(""))]
        by_simulation = [effect in set(filter(None, s.split(","))) for s in group["added by simulation"].fillna("")]
        wrong = [bool(a - {effect, *PARTS.get(effect, ())}) for a in added]
        rows[key if len(by) > 1 else effect] = {
            "systems": len(group),
            "ranked first %": 100 * float((group["first effect"] == effect).mean()),
            "added %": 100 * float(np.mean([effect in a for a in added])),
            "added by simulation %": 100 * float(np.mean(by_simulation)),
            "added first %": 100 * float(group["first added"].isin({effect, *PARTS.get(effect, ())}).mean()),
            "equation error fall (median x)": group["equation error fall"].median(),
            "free-run error fall (median x)": group["free-run error fall"].median(),
            "free-run error fall (least x)": group["free-run error fall"].min(),
            "start to final fall (median x)": group["start to final fall"].median(),
            "start to final fall (least x)": group["start to final fall"].min(),
            "wrong addition %": 100 * float(np.mean(wrong)),
            "gap said %": 100 * float(group["gap said"].astype(float).mean()),
            "train gap (median x)": group["train gap"].median(),
            "most often first": group["first effect"].mode().iloc[0] if group["first effect"].notna().any() else None,
        }
    table = pd.DataFrame.from_dict(rows, orient="index")
    names = ["hidden effect", *by[1:]]
    if len(by) > 1:  # (no system finished: an empty table, not an error after a long run)
        table.index = pd.MultiIndex.from_tuples(table.index, names=names) if rows else \
            pd.MultiIndex.from_arrays([[]] * len(names), names=names)
    return table.rename_axis(names)


def example_runs(one, cases, name: str) -> pd.DataFrame:
    """The rows of ``one(seed, *case)`` for every seed of the environment's ``SEEDS``
    (``first:last``, the report seeds 1000:1010 by default) and every case, on 2 workers,
    written to ``OUT/name.csv`` (``OUT`` from the environment, the working folder by
    default): the harness of the held-out examples (``examples/gapped_records.py``, ...)."""
    import os

    first, last = map(int, os.environ.get("SEEDS", "1000:1010").split(":"))
    rows = Parallel(n_jobs=2)(delayed(one)(seed, *case) for seed in range(first, last) for case in cases)
    frame = pd.DataFrame(rows)
    frame.to_csv(os.path.join(os.environ.get("OUT", "."), f"{name}.csv"), index=False)
    return frame


def with_baseline(frame: pd.DataFrame, script: str, name: str) -> pd.DataFrame:
    """``frame`` (an example's rows by :func:`example_runs`, ``version = "this"``) and, with
    ``BASELINE`` in the environment (a folder holding an older ``cvxid/``), the same rows
    by that copy: ``script`` run again in its own process on it, with ``ROWS_ONLY`` set to
    the file name its rows go to (the script then writes them and stops, before importing
    this function, which an older copy may lack), ``version = "baseline"``."""
    import os
    import subprocess
    import sys

    frame = frame.assign(version="this")
    baseline = os.environ.get("BASELINE")
    if not baseline:
        return frame
    subprocess.run([sys.executable, script], check=True,
                   env={**os.environ, "PYTHONPATH": baseline, "ROWS_ONLY": f"{name}_baseline"})
    rows = pd.read_csv(os.path.join(os.environ.get("OUT", "."), f"{name}_baseline.csv"))
    return pd.concat([rows.assign(version="baseline"), frame])


def delay_errors(groups) -> dict[str, pd.Series]:
    """Per group of rows with ``tau error %`` and ``covers``: the systems, the median and
    90th percentile of |tau error| % and the intervals that cover the truth."""
    return {"systems": groups.size(), "median |tau error| %": groups["tau error %"].apply(lambda e: e.abs().median()),
            "p90 |tau error| %": groups["tau error %"].apply(lambda e: e.abs().quantile(0.9)),
            "covers": groups["covers"].sum()}


def by_duration(frame: pd.DataFrame) -> pd.DataFrame:
    """The same systems at several record lengths (``frame`` of :func:`heldout` runs at each
    length, concatenated) side by side: |tau error| % and worst other % per length, and
    whether the longest record's tau is at least as accurate as the shortest's."""
    ok = frame[frame["status"] == "ok"].assign(**{"|tau err| %": lambda f: f["tau error %"].abs()})
    wide = ok.pivot_table(index=["seed", "effect", "noise"], columns="duration",
                          values=["|tau err| %", "worst other %"])
    short, long = min(ok["duration"]), max(ok["duration"])
    wide[("longest at least as accurate", "")] = wide[("|tau err| %", long)] <= wide[("|tau err| %", short)]
    return wide
