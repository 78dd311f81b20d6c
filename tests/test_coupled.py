"""Coupled equations (the flexible joint): simulation and joint identification with ties."""

import numpy as np
import pytest

from cvxid.identify.system import identify_system
from cvxid.model.system import SystemSpec
from cvxid.regression.builder import SystemBuilder
from cvxid.tools.flexible_joint import (
    flexible_joint,
    flexible_joint_experiment,
    flexible_joint_specs,
)


def test_simulated_joint_satisfies_its_equations():
    system, truth = flexible_joint(coulomb=0.05)
    e = flexible_joint_experiment(system, truth, "sine", duration=5.0)
    t, th, al = e.time, e.output("theta"), e.output("alpha")
    vt, va = e.velocities["theta"], e.velocities["alpha"]
    lagged = np.interp(t - truth["tau"], t, th)
    lagged[t < truth["tau"]] = 0.0
    friction = truth["f_c"] * np.tanh(vt / 0.05)
    r = (truth["J_eq"] * np.gradient(vt, t) + (truth["B_eq"] + truth["b"]) * vt - truth["k_s"] * al
         - truth["B_l"] * va + friction - e.input("u") + truth["gain"] * lagged)
    assert np.median(np.abs(r)) < 1e-5 * np.abs(e.input("u")).max()


def test_joint_identification_recovers_delay_and_stiffness_noise_free():
    system, truth = flexible_joint(coulomb=0.0)
    e = flexible_joint_experiment(system, truth, "sine", duration=20.0)
    specs = flexible_joint_specs(truth["gain"])
    system = SystemSpec(specs, ties=(("alpha:theta'", "theta:theta'", -1.0),))
    result = identify_system(system, SystemBuilder(specs, e, velocity="measured"))
    theta, alpha = result.models["theta"].coefficients, result.models["alpha"].coefficients
    assert result.tau == pytest.approx(truth["tau"], rel=5e-3)
    assert -theta["alpha"] == pytest.approx(truth["k_s"], rel=5e-3)
    assert theta["theta''"] == pytest.approx(truth["J_eq"], rel=5e-3)
    assert alpha["theta'"] == pytest.approx(-theta["theta'"], rel=1e-9)  # the tie
    assert alpha["alpha"] == pytest.approx(truth["k_s"] * (1 + truth["J_eq"] / truth["J_l"]), rel=5e-3)
