r"""The paper's section 5 rig: Quanser's rotary flexible joint under delayed proportional
control, simulated by cvxid.

Motor angle :math:`\theta` and link deflection :math:`\alpha`; the controller feeds
:math:`\theta` back with a delay :math:`\tau`; Table 3's constants (and :math:`J_{eq}` as
Table 5 implies); an optional Coulomb friction on the motor side, the effect the paper
found in its real rig.  :func:`flexible_joint_specs` gives the starting model (without the
friction) that ``problems/flexible_joint.toml`` writes out as a spec.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError
from cvxid.model.delay import DelayedFeedback
from cvxid.model.equation import ModelSpec
from cvxid.model.library import Library
from cvxid.model.terms import Sign, parse_term
from cvxid.simulate import CoupledSystem, Equation, simulate_coupled

QUANSER = {
    # Table 3 of the paper (J_eq as its Table 5 implies: 0.0102 - 0.008121)
    "J_eq": 0.00208, "J_l": 0.0038, "B_eq": 0.015, "B_l": 0.004, "k_s": 1.3,
    "k_g": 70.0, "k_t": 7.68e-3, "k_m": 7.68e-3, "R_m": 2.6, "eta_g": 0.9, "eta_m": 0.69,
}


def flexible_joint(k_p: float = 3.16, tau: float = 0.2, coulomb: float = 0.05, params: dict | None = None,
                   stiction_speed: float = 0.05):
    """The rotary flexible joint under proportional control of the delayed theta:

    .. math::

        J_{eq}\\ddot\\theta + (B_{eq}+b)\\dot\\theta - k_s\\alpha - B_l\\dot\\alpha
            + f_c\\,\\mathrm{sign}\\,\\dot\\theta = a k_p\\theta_d - a k_p\\,\\theta(t-\\tau)

        J_{eq}\\ddot\\alpha - (B_{eq}+b)\\dot\\theta + k_s(1+J_{eq}/J_l)\\alpha
            + B_l(1+J_{eq}/J_l)\\dot\\alpha - f_c\\,\\mathrm{sign}\\,\\dot\\theta
            = -a k_p\\theta_d + a k_p\\,\\theta(t-\\tau)

    with :math:`a = \\eta_g k_g \\eta_m k_t / R_m` and :math:`b = a k_g k_m` (the motor's
    back-emf).  The shared input is :math:`u = a k_p \\theta_d`.  The friction is simulated as
    :math:`f_c \\tanh(\\dot\\theta/v_s)` with ``stiction_speed`` :math:`v_s`: an ideal sign
    makes the integrator chatter where the joint sticks, which no sampled regression column
    reproduces.  Returns the system and the true physical constants."""
    p = dict(QUANSER, **(params or {}))
    a = p["eta_g"] * p["k_g"] * p["eta_m"] * p["k_t"] / p["R_m"]
    b = a * p["k_g"] * p["k_m"]
    ratio = 1 + p["J_eq"] / p["J_l"]
    th = [parse_term(n, ("theta", "alpha")) for n in ("theta'", "alpha", "alpha'")]
    al = [parse_term(n, ("alpha", "theta")) for n in ("theta'", "alpha", "alpha'")]
    friction = [Sign("theta", stiction_speed)] if coulomb else []
    theta = Equation("theta", p["J_eq"], tuple(th + friction),
                     (p["B_eq"] + b, -p["k_s"], -p["B_l"]) + ((coulomb,) if coulomb else ()), 1.0, -a * k_p)
    alpha = Equation("alpha", p["J_eq"], tuple(al + friction),
                     (-(p["B_eq"] + b), p["k_s"] * ratio, p["B_l"] * ratio) + ((-coulomb,) if coulomb else ()),
                     -1.0, a * k_p)
    truth = dict(p, a=a, b=b, k_p=k_p, tau=tau, f_c=coulomb, gain=a * k_p)
    return CoupledSystem((theta, alpha), "theta", tau, "zero"), truth


def flexible_joint_experiment(system: CoupledSystem, truth: dict, reference: str, duration: float = 60.0,
                              dt: float = 1e-3, noise: float = 0.0, seed: int = 0) -> Experiment:
    """Closed-loop data of the joint: sine (training) or square (test) reference of
    amplitude 2 rad at 0.66 Hz; outputs theta, alpha; input u = a k_p theta_d."""
    t = np.arange(int(round(duration / dt)) + 1) * dt
    if reference == "sine":
        ref = lambda s: 2.0 * np.sin(2 * np.pi * 0.66 * s)  # noqa: E731
    elif reference == "square":
        ref = lambda s: 2.0 * np.where(np.sin(2 * np.pi * 0.66 * s) >= 0, 1.0, -1.0)  # noqa: E731
    else:
        raise CvxidError(f"reference must be 'sine' or 'square', got {reference!r}")
    gain = truth["a"] * truth["k_p"]
    x, v = simulate_coupled(system, t, lambda s: gain * ref(s), {"theta": 0.0, "alpha": 0.0},
                            {"theta": 0.0, "alpha": 0.0})
    rng = np.random.default_rng(seed)
    outputs = {c: x[c] + noise * rng.standard_normal(t.size) for c in x}
    u = gain * ref(t)
    return Experiment(t, outputs, {"u": u}, name=reference, velocities=v)


def flexible_joint_specs(gain: float, library: Sequence[str] = ("theta'", "alpha", "alpha'"),
                         tau_max: float = 0.5) -> dict[str, ModelSpec]:
    """The two equations' model specs (exact shared delay of theta, known gain)."""
    def spec(coord, other, inp, g):
        delay = DelayedFeedback("theta", 0, g, method="exact", tau_max=tau_max)
        lib = Library(parse_term(n, (coord, other)) for n in library)
        return ModelSpec(lib, coordinate=coord, input=inp, delay=delay, nonnegative=(f"{coord}''",), others=(other,))

    return {"theta": spec("theta", "alpha", "u", -gain), "alpha": spec("alpha", "theta", "-u", gain)}
