r"""The identified model in python-control.

The delayed feedback :math:`b\,x^{(q)}(t-\tau)` becomes a Padé approximation
:math:`e^{-s\tau} \approx N(s)/D(s)` (``control.pade``) realised in state space, so the
model is an ordinary nonlinear system (``control.nlsys``) and its linearisation at rest a
rational transfer function:

.. math::

    \frac{X(s)}{F(s)} = \frac{1}{m s^2 + c s + k - b\, s^q\, N(s)/D(s)},

with :math:`c = \partial g/\partial \dot x` and :math:`k = \partial g/\partial x` at rest
(the paper's :math:`b_0 x(t-\tau) + b_1 \dot x(t-\tau)`: :math:`(b_0 + b_1 s)\,N(s)/D(s)`).
An input delay :math:`u(t-\tau_u)` (:mod:`cvxid.model.input_delay`) is a second Padé
approximation in series before the plant.
"""

from __future__ import annotations

import warnings

import control
import numpy as np

from cvxid.errors import CvxidError, CvxidWarning


def _pade(tau: float, order: int):
    if order < 1:
        raise CvxidError(f"the Padé order must be at least 1, got {order}")
    num, den = control.pade(tau, order)
    return control.tf2ss(control.tf(num, den))


def _linear_terms(system) -> tuple[float, float]:
    """:math:`\\partial g/\\partial x` and :math:`\\partial g/\\partial \\dot x` at rest (central
    differences), without the terms that have none there: a term whose difference quotient
    grows as the step shrinks jumps at rest (a dry friction ``sign(x')``: its 0.8 / 1e-6
    was added to the damping, 8e5, without a word); it is left out with a warning."""
    coord = system.coordinate

    def slopes(term, h):
        def value(x, v):
            return float(np.ravel(term.evaluate({coord: np.array([x]), coord + "'": np.array([v])}))[0])
        return np.array([value(h, 0.0) - value(-h, 0.0), value(0.0, h) - value(0.0, -h)]) / (2 * h)

    k = c = 0.0
    jumps = []
    for term, coefficient in zip(system.terms, np.atleast_1d(system.coefficients)):
        coarse, fine = slopes(term, STEP), slopes(term, STEP / 100)
        if np.any(np.abs(fine) > STEEPER * np.abs(coarse) + 1e-300):
            jumps.append(term.name)
            continue
        k, c = k + coefficient * coarse[0], c + coefficient * coarse[1]
    if jumps:
        warnings.warn(f"{', '.join(jumps)} {'has' if len(jumps) == 1 else 'have'} no finite derivative at rest (a "
                      "jump or an infinite slope at 0): left out of the linearisation, which holds for motions "
                      "where such a term stays constant (a dry friction: in steady sliding); simulate the model "
                      "(to_nlsys) to see its effect",
                      CvxidWarning, stacklevel=4)
    return k, c


STEP = 1e-6
"""The central differences' step at rest (a term's slope is also read at a step 100 times
smaller: one that grows :data:`STEEPER` times there has no finite slope at rest)."""
STEEPER = 1.2
"""A smooth term's two slopes agree to :math:`O(h^2)`; a jump's grows 100-fold, a power
:math:`|\\dot x|^p`'s :math:`100^{1-p}`-fold (``sign(x')*abs(x')^0.5``: 10; a steep
``tanh(50 x')`` stays at 1)."""


def linearized_tf(model, pade_order: int = 6):
    """Transfer function f -> x of the model linearised at rest (see the module docstring)."""
    system = model.system()
    k, c = _linear_terms(system)
    plant = control.tf([1.0], [float(system.mass), c, k])
    if system.gain or system.rate_gain:
        num, den = control.pade(float(system.tau), pade_order)
        fed = [float(system.rate_gain), float(system.gain)] + [0.0] * system.derivative  # b1 s + b0, or b s
        plant = control.feedback(plant, control.tf(num, den) * control.tf(fed, [1.0]), sign=+1)
    tau_u = model.spec.input_tau
    if tau_u:
        num, den = control.pade(tau_u, pade_order)
        plant = control.tf(num, den) * plant
    plant.update_names(inputs=[model.spec.input], outputs=[system.coordinate])  # (as to_nlsys names them)
    return plant


def to_nlsys(model, pade_order: int = 6):
    """A ``control.nlsys`` with states (x, x', the feedback's Padé states, the input
    delay's Padé states), input f and output x."""
    system = model.system()
    coord = system.coordinate
    coefs = np.atleast_1d(system.coefficients)
    mass, gain, rate_gain = float(system.mass), float(system.gain), float(system.rate_gain)
    pade = _pade(float(system.tau), pade_order) if gain or rate_gain else None
    npade = 0 if pade is None else pade.nstates
    lag = _pade(model.spec.input_tau, pade_order) if model.spec.input_tau else None  # the input's delay
    nlag = 0 if lag is None else lag.nstates

    def g(x, v):
        states = {coord: np.array([x]), coord + "'": np.array([v])}
        return sum(c * float(np.ravel(t.evaluate(states))[0]) for t, c in zip(system.terms, coefs))

    def update(t, state, u, params):
        x, v, z, w = state[0], state[1], state[2:2 + npade], state[2 + npade:]
        f = float(np.ravel(u)[0])
        dw = np.zeros(0)
        if lag is not None:
            f, dw = float((lag.C @ w + lag.D.ravel() * f)[0]), (lag.A @ w + lag.B.ravel() * f).ravel()
        feed = 0.0
        dz = np.zeros(0)
        if pade is not None:  # (one Padé delay of the fed-back combination: b x + b1 x', or b x')
            signal = gain * x + rate_gain * v if system.derivative == 0 else gain * v
            feed = float((pade.C @ z + pade.D.ravel() * signal)[0])
            dz = (pade.A @ z + pade.B.ravel() * signal).ravel()
        a = (f + feed - g(x, v)) / mass
        return np.concatenate([[v, a], dz, dw])

    return control.nlsys(
        update, lambda t, state, u, params: state[:1], states=2 + npade + nlag, inputs=[model.spec.input],
        outputs=[coord], name="cvxid_model",
    )
