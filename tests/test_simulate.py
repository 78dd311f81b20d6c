"""The delay-differential integrator."""

import numpy as np
import pytest

from cvxid.model.terms import parse_term
from cvxid.simulate import SimulationDiverged, System, simulate

T = np.arange(5001) * 2e-4  # 1 s at the paper's step


def linear(c=0.4, k=6.0, m=1.3, **kw):
    terms = (parse_term("x'"), parse_term("x"))
    return System(terms, np.array([c, k]), m, **kw)


def test_free_linear_oscillator_matches_closed_form():
    m, c, k = 1.3, 0.4, 6.0
    x, v = simulate(linear(c, k, m), T, lambda t: 0 * t, 1.0, 0.0)
    s, w = -c / (2 * m), np.sqrt(k / m - (c / (2 * m)) ** 2)
    exact = np.exp(s * T) * (np.cos(w * T) - s / w * np.sin(w * T))
    assert np.abs(x - exact).max() < 1e-10


@pytest.mark.parametrize("tau, history", [(0.2, "zero"), (0.2, "initial"), (0.2013, "initial")])
def test_delayed_duffing_converges_at_fourth_order(tau, history):
    # on a coarse 20 ms grid (at the paper's 0.2 ms the error is round-off), halving the
    # step divides the error by 2^4: the measured orders are 4.1 to 4.3
    coarse = np.arange(101) * 2e-2
    terms = tuple(parse_term(s) for s in ["x'", "x^2 x'", "x'^3", "x", "x^3"])
    sysm = System(terms, np.array([1, 1, 1, 6, 2.0]), 1.0, "x", 2.0, tau, 0, history)
    force = lambda t: 10 * np.sin(4 * t) + 40 * np.sin(4 * t**2)
    reference, _ = simulate(sysm, coarse, force, 1.0, 0.0, substeps=16)
    errors = [np.abs(simulate(sysm, coarse, force, 1.0, 0.0, substeps=k)[0] - reference).max() for k in (1, 2, 4)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((orders > 3.7) & (orders < 4.6)), orders


def test_zero_history_means_no_feedback_before_tau():
    # before t = tau the delayed loop is open: identical to the system without delay
    terms = (parse_term("x'"), parse_term("x"))
    with_delay = System(terms, np.array([0.4, 6.0]), 1.0, "x", 2.0, 0.5, 0, "zero")
    no_delay = System(terms, np.array([0.4, 6.0]), 1.0)
    a, _ = simulate(with_delay, T, np.sin, 1.0, 0.0)
    b, _ = simulate(no_delay, T, np.sin, 1.0, 0.0)
    before = T <= 0.5
    np.testing.assert_allclose(a[before], b[before], atol=1e-12)
    assert np.abs(a[~before] - b[~before]).max() > 1e-3


def test_batch_equals_single_runs():
    terms = (parse_term("x'"), parse_term("x"))
    coefs = np.array([[0.4, 6.0], [0.8, 3.0]])
    sysm = System(terms, coefs, 1.0, "x", 2.0, np.array([0.2, 0.3]), 0, "zero")
    xb, _ = simulate(sysm, T, np.sin, 1.0, 0.0)
    for i in range(2):
        xi, _ = simulate(System(terms, coefs[i], 1.0, "x", 2.0, [0.2, 0.3][i], 0, "zero"), T, np.sin, 1.0, 0.0)
        np.testing.assert_allclose(xb[:, i], xi, atol=1e-12)


def test_a_batchs_columns_are_the_runs_one_at_a_time_and_its_first_divergence_is_said():
    """A batch's variants run in parallel threads: each column is its run alone, and the
    one variant that diverges stops the batch at its own time."""

    terms = (parse_term("x'"), parse_term("x"))
    coefs = np.array([[0.4, 6.0], [0.8, 3.0], [0.2, 9.0], [1.5, 4.0], [0.3, 5.0]])
    taus = np.array([0.2, 0.3, 0.1, 0.25, 0.05])
    xb, _ = simulate(System(terms, coefs, 1.0, "x", 2.0, taus, 0, "zero"), T, np.sin, 1.0, 0.0)
    for i in range(5):
        xi, _ = simulate(System(terms, coefs[i], 1.0, "x", 2.0, taus[i], 0, "zero"), T, np.sin, 1.0, 0.0)
        np.testing.assert_allclose(xb[:, i], xi, rtol=0, atol=1e-12)
    t = np.arange(20001) * 1e-3
    unstable = np.array([[0.0, 6.0], [0.0, 6.0], [0.0, 6.0], [0.0, -50.0]])
    with pytest.raises(SimulationDiverged) as alone:
        simulate(System(terms, unstable[3], 1.0), t, lambda t: 0 * t, 1.0, 0.0)
    with pytest.raises(SimulationDiverged) as batch:
        simulate(System(terms, unstable, 1.0), t, lambda t: 0 * t, 1.0, 0.0)
    assert str(batch.value) == str(alone.value) and "diverged at t = " in str(batch.value)


def test_divergence_is_a_clear_error():
    unstable = System((parse_term("x"),), np.array([-50.0]), 1.0)
    with pytest.raises(SimulationDiverged, match="diverged at t = .* unstable"):
        simulate(unstable, np.arange(20001) * 1e-3, lambda t: 0 * t, 1.0, 0.0)


def test_user_terms_run_in_the_python_integrator_like_the_compiled_one():
    from cvxid.model.terms import FunctionTerm

    cubic = FunctionTerm("cube", "a user's cubic stiffness", lambda s: s["x"] ** 3, frozenset({"x"}))
    force = lambda t: 10 * np.sin(4 * t)
    compiled = System((parse_term("x'"), parse_term("x^3")), np.array([1.0, 2.0]), 1.0, "x", 2.0, 0.2, 0, "zero")
    python = System((parse_term("x'"), cubic), np.array([1.0, 2.0]), 1.0, "x", 2.0, 0.2, 0, "zero")
    a, _ = simulate(compiled, T, force, 1.0, 0.0)
    b, _ = simulate(python, T, force, 1.0, 0.0)
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_coulomb_friction_sticks_below_its_bound_and_slides_above():
    """Stick and slip: a force below the friction bound leaves the mass at rest (a plain
    sign would chatter it along); above, it accelerates at (f - F_c) / m."""
    t = np.arange(0, 2, 1e-3)
    friction = System((parse_term("sign(x')"),), np.array([1.0]), 2.0)
    x, v = simulate(friction, t, np.full_like(t, 0.6), 0.0, 0.0)
    assert np.all(x == 0.0) and np.all(v == 0.0)
    x, v = simulate(friction, t, np.full_like(t, 3.0), 0.0, 0.0)
    assert v[-1] == pytest.approx((3.0 - 1.0) / 2.0 * t[-1], rel=1e-3)


def test_the_shortest_delay_of_a_batch_sets_its_substeps():
    """The rule the integrator and the output-error Jacobian share (the Jacobian reuses the
    solver's own residual only when its batch, reaching tau - h, integrates the same way)."""
    from cvxid.simulate import delay_substeps

    dt = 4e-3
    tau = dt / 2 * (1 + 3e-6)  # just above dt/2: two sub-steps alone
    assert delay_substeps([tau], dt) == 2
    assert delay_substeps([tau, tau * (1 - 1e-5)], dt) == 3  # its central difference needs three
    assert delay_substeps([0.15, 0.15 * (1 - 1e-5)], dt) == 1
    assert delay_substeps([dt / 100], dt) == 1  # below dt / 16 a delay acts at once


def test_coulomb_friction_moves_the_simulation_continuously_with_its_parameters():
    """A sliding motion stops where its velocity reaches zero (the step split there), and
    rests under the force that keeps it at rest, up to its bound: continuous in the state
    and the coefficients.  Over 401 friction levels 1e-5 apart (relative), a stick-slip
    response moves by similar amounts between neighbours (largest step within 5x the median;
    measured 1.00, 1.02 with a clip at every stage); Karnopp's band, which balanced the
    forces within a step's friction of rest and jumped at its edge, made it jump (20)."""
    t = np.arange(0, 8, 1e-3)
    levels = 0.8 * (1 + 1e-5 * np.arange(-200, 201))
    coefs = np.column_stack([np.full(levels.size, 0.4), np.full(levels.size, 6.0), levels])
    system = System((parse_term("x'"), parse_term("x"), parse_term("sign(x')")), coefs, 1.0, "x", 1.5, 0.15)
    force = lambda s: 3 * np.sin(1.9 * s) + 2 * np.sin(4.7 * s + 1) + 1.5 * np.sin(8.3 * s + 2)  # noqa: E731
    x, _ = simulate(system, t, force, 0.3, 0.0)
    moves = np.linalg.norm(np.diff(x, axis=1), axis=0)
    assert np.max(moves) < 5 * np.median(moves), np.max(moves) / np.median(moves)


def test_coulomb_friction_is_integrated_to_the_accuracy_of_rk4():
    """A sliding coordinate stops at the instant its velocity reaches zero (the step split
    there), then rests exactly: at the sample step the stick-slip response of
    `hidden_friction`'s truth is within 1e-6 of a 64-fold finer integration (measured 5e-8;
    the clip at every stage, which brought the motion to rest over a step, was first order:
    7.9e-4, halving with each halving of the step)."""
    t = np.arange(0, 8, 1e-3)
    system = System((parse_term("x'"), parse_term("x"), parse_term("sign(x')")), np.array([0.4, 6.0, 0.8]), 1.0, "x",
                    1.5, 0.15)
    force = lambda s: 3 * np.sin(1.9 * s) + 2 * np.sin(4.7 * s + 1) + 1.5 * np.sin(8.3 * s + 2)  # noqa: E731
    x, v = simulate(system, t, force, 0.3, 0.0)
    fine, _ = simulate(system, t, force, 0.3, 0.0, substeps=64)
    assert np.max(np.abs(x - fine)) < 1e-6
    assert np.sum(v == 0.0) > 100  # it sticks, at rest to the last bit


def test_coulomb_friction_of_two_coupled_coordinates_converges():
    """Two coordinates with their own friction, one's friction also acting on the other:
    within 1e-4 of a 64-fold finer integration at the sample step (measured 2.1e-5; the clip
    at every stage 1.2e-3), and closer at finer steps (7.6e-6 at half, 1.3e-6 at a quarter;
    before the push of a sliding friction came ahead of the other's clip, 4.8e-4 at a
    quarter: the coordinate it held crept)."""
    from cvxid.simulate import CoupledSystem, Equation, simulate_coupled

    def terms(*names):
        return tuple(parse_term(n, ("x", "y")) for n in names)

    equations = (Equation("x", 1.0, terms("x'", "x", "y", "sign(x')"), (0.3, 4.0, -1.0, 0.6), delay_gain=0.5),
                 Equation("y", 2.0, terms("y'", "y", "x", "sign(y')", "sign(x')"), (0.2, 3.0, -1.0, 0.4, -0.2),
                          input_gain=-1.0))
    system = CoupledSystem(equations, "x", 0.1)
    t = np.arange(8001) * 1e-3
    force = lambda s: 3 * np.sin(2.3 * s) + 2 * np.sin(7.1 * s)  # noqa: E731
    runs = [simulate_coupled(system, t, force, {"x": 0.2, "y": 0.0}, {"x": 0.0, "y": 0.0}, substeps=s)[0]
            for s in (1, 4, 64)]
    errors = [max(np.max(np.abs(run[c] - runs[-1][c])) for c in "xy") for run in runs[:2]]
    assert errors[0] < 1e-4 and errors[1] < 5e-6


@pytest.mark.parametrize("level, derivative", [(0.8, 0), (0.0, 0), (-0.5, 0), (1.2, 1)])
def test_coulomb_friction_is_the_same_in_the_python_integrator(level, derivative):
    """A user's own term sends a system to the Python integrator: its friction (positive:
    stops located, the clip at rest; zero; negative: a plain sign that pushes; with the
    velocity fed back, whose history's slopes read the stops) is the compiled one's."""
    from cvxid.model.terms import FunctionTerm

    t = np.arange(0, 4, 1e-3)
    force = lambda s: 3 * np.sin(1.9 * s) + 2 * np.sin(4.7 * s + 1)  # noqa: E731
    nothing = FunctionTerm("nothing", "a user's term worth zero", lambda s: 0 * s["x"], frozenset({"x"}))
    terms = (parse_term("x'"), parse_term("x"), parse_term("sign(x')"))
    coefs = np.array([0.4, 6.0, level])
    compiled = System(terms, coefs, 1.0, "x", 1.5, 0.15, derivative)
    python = System(terms + (nothing,), np.r_[coefs, 1.0], 1.0, "x", 1.5, 0.15, derivative)
    a, _ = simulate(compiled, t, force, 0.3, 0.0)
    b, _ = simulate(python, t, force, 0.3, 0.0)
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_a_batch_of_starts_runs_as_the_same_starts_one_at_a_time():
    """The initial-state search simulates its Jacobian's starts in one batch: each column must be the run from
    that start alone (two coupled equations, three starts)."""
    from cvxid.simulate import CoupledSystem, Equation, simulate_coupled

    def terms(*names):
        return tuple(parse_term(n, ("x", "y")) for n in names)

    equations = (Equation("x", 1.0, terms("x'", "x", "y"), (0.3, 4.0, -1.0), delay_gain=0.5),
                 Equation("y", 2.0, terms("y'", "y", "x"), (0.2, 3.0, -1.0), input_gain=-1.0))
    system = CoupledSystem(equations, "x", 0.1)
    t = np.arange(2001) * 1e-3
    force = lambda s: np.sin(2.3 * s) + 0.5 * np.sin(7.1 * s)  # noqa: E731
    x0, v0 = {"x": np.array([0.0, 0.2, -0.1]), "y": np.array([0.1, 0.0, 0.3])}, {"x": np.zeros(3), "y": np.ones(3)}
    batch, _ = simulate_coupled(system, t, force, x0, v0)
    for b in range(3):
        alone, _ = simulate_coupled(system, t, force, {c: x0[c][b] for c in x0}, {c: v0[c][b] for c in v0})
        for c in ("x", "y"):
            assert batch[c].shape == (t.size, 3) and alone[c].shape == (t.size,)
            np.testing.assert_allclose(batch[c][:, b], alone[c], rtol=0, atol=1e-12)


def test_a_motion_that_stops_rests_exactly():
    """A mass sliding at 1 against a friction of 1.2 under a force of 0.6 stops at
    t = 1 / 0.6 and rests: after the stop its velocity is exactly 0 and its position is
    v0^2 / (2 * 0.6) to round-off (the friction at rest is the force that keeps it there,
    subtracted as a force: as a bound times a direction it left velocities of 1e-20 that
    started a stop at every step)."""
    t = np.arange(0, 4, 1e-2)
    friction = System((parse_term("sign(x')"),), np.array([1.2]), 1.0)
    x, v = simulate(friction, t, np.full_like(t, 0.6), 0.0, 1.0)
    resting = t > 1 / 0.6 + 1e-2
    assert np.all(v[resting] == 0.0) and np.all(x[resting] == x[-1])
    assert x[-1] == pytest.approx(1 / 1.2, abs=1e-12)


def test_a_friction_pushing_a_coordinate_that_its_own_friction_holds_leaves_it_at_rest():
    """x slides against its friction, which also pushes y with 0.3, below y's own bound of
    1: y stays exactly at rest, at every step size (the push is added before y's clip; after
    it, y crept by 1.3e-3 at a step of 0.01), in both integrators."""
    from cvxid.model.terms import FunctionTerm
    from cvxid.simulate import CoupledSystem, Equation, simulate_coupled

    def terms(*names):
        return tuple(parse_term(n, ("x", "y")) for n in names)

    nothing = FunctionTerm("nothing", "a user's term worth zero", lambda s: 0 * s["x"], frozenset({"x"}))
    t = np.arange(0, 3, 1e-2)
    for extra in ((), (nothing,)):
        equations = (Equation("x", 1.0, terms("sign(x')") + extra, (0.5,) + (1.0,) * len(extra)),
                     Equation("y", 1.0, terms("sign(y')", "sign(x')"), (1.0, -0.3)))
        for substeps in (1, 4):
            X, V = simulate_coupled(CoupledSystem(equations, "x", 0.0), t, np.zeros_like(t), {"x": 0.0, "y": 0.0},
                                    {"x": 1.0, "y": 0.0}, substeps=substeps)
            assert np.all(X["y"] == 0.0) and np.all(V["y"] == 0.0)
            assert X["x"][-1] == pytest.approx(1.0, abs=1e-12)  # v0^2 / (2 * 0.5)


def test_more_stops_in_one_step_than_it_locates_do_not_push_back():
    """Ten coordinates that all stop within the first step of 0.01 s: the first eight stops
    are located (x = v0^2 / 2 to round-off), the rest of the step takes every friction's
    clip, which slows the last two without pushing them back (with a sliding direction kept
    past the budget they ended the step at v = -0.005); they stop in the next step
    (measured: 2 % past v0^2 / 2)."""
    from cvxid.simulate import MAX_EVENTS, CoupledSystem, Equation, simulate_coupled

    names = tuple("abcdefghij")
    equations = tuple(Equation(c, 1.0, (parse_term(f"sign({c}')", names),), (1.0,)) for c in names)
    t = np.arange(0, 0.05, 1e-2)
    v0 = {c: 1e-3 * (i + 1) for i, c in enumerate(names)}
    X, V = simulate_coupled(CoupledSystem(equations, "a", 0.0), t, np.zeros_like(t), dict.fromkeys(names, 0.0), v0)
    assert all(np.all(V[c][2:] == 0.0) and 0.0 <= V[c][1] < v0[c] for c in names)
    errors = [X[c][-1] / (v0[c] ** 2 / 2) - 1 for c in names]
    assert max(map(abs, errors[:MAX_EVENTS])) < 1e-12 and max(map(abs, errors)) < 0.05


def test_a_stribeck_friction_is_a_friction_too():
    """``sign(x') * exp(-(x'/0.05)^2)`` beside a Coulomb friction: its bound joins the
    Coulomb one (the sign times a factor is a friction whose bound is the factor), so its
    stops are located too: within 1e-6 of a 64-fold finer integration (measured 8.9e-8; as a
    sign switched inside a step, 7.3e-4), moving smoothly with its coefficient (largest move
    between neighbours 1e-5 apart within 5x the median: measured 1.00; 77 before), and the
    same in the Python integrator."""
    from cvxid.model.terms import FunctionTerm

    t = np.arange(0, 8, 1e-3)
    force = lambda s: 3 * np.sin(1.9 * s) + 2 * np.sin(4.7 * s + 1) + 1.5 * np.sin(8.3 * s + 2)  # noqa: E731
    terms = (parse_term("x'"), parse_term("x"), parse_term("sign(x')"), parse_term("sign(x') * exp(-(x' / 0.05)^2)"))
    system = System(terms, np.array([0.4, 6.0, 0.6, 0.3]), 1.0, "x", 1.5, 0.15)
    x, _ = simulate(system, t, force, 0.3, 0.0)
    fine, _ = simulate(system, t, force, 0.3, 0.0, substeps=64)
    assert np.max(np.abs(x - fine)) < 1e-6
    levels = 0.3 * (1 + 1e-5 * np.arange(-50, 51))
    coefs = np.column_stack([np.full((levels.size, 3), [0.4, 6.0, 0.6]), levels])
    swept, _ = simulate(System(terms, coefs, 1.0, "x", 1.5, 0.15), t, force, 0.3, 0.0)
    moves = np.linalg.norm(np.diff(swept, axis=1), axis=0)
    assert np.max(moves) < 5 * np.median(moves)
    nothing = FunctionTerm("nothing", "a user's term worth zero", lambda s: 0 * s["x"], frozenset({"x"}))
    python, _ = simulate(System(terms + (nothing,), np.array([0.4, 6.0, 0.6, 0.3, 1.0]), 1.0, "x", 1.5, 0.15),
                         t[:3000], force, 0.3, 0.0)
    np.testing.assert_allclose(python, x[:3000], atol=1e-12)


@pytest.mark.parametrize("effect", ["coulomb", "stribeck"])
def test_dry_friction_of_systems_drawn_at_random_is_integrated_below_the_noise(effect):
    """Held-out report systems 1000-1002 (other masses, delays, gains, forcing; 8 s from
    mid-motion): at the sample step within 1e-3 noise units of a 64-fold finer run
    (`python examples/friction_integrator.py`, seeds 1000-1019: at most 4.4e-5 with Coulomb
    and 7.9e-4 with Stribeck friction; the clip at every stage, median 0.12 and 0.10, up
    to 8.6 and 12.8)."""
    from cvxid.tools.heldout import DT, draw

    for seed in (1000, 1001, 1002):
        oscillator = draw(seed, effect, 0.01, 8.0)
        skip = round(oscillator.train.pre / DT)
        t = (np.arange(skip + 8001) - skip) * DT
        coarse, _ = simulate(oscillator.system, t, oscillator.train, 0.0, 0.0)
        fine, _ = simulate(oscillator.system, t, oscillator.train, 0.0, 0.0, substeps=64)
        assert np.max(np.abs(coarse - fine)[skip:]) < 1e-3 * 0.01


def test_an_offset_prints_as_a_number_not_times_one():
    """An eleventh outside check read '- 0.165412 1' in an equation: the constant term
    prints as its coefficient alone, in text and in LaTeX."""
    from cvxid.identified import IdentifiedModel
    from cvxid.model.equation import ModelSpec
    from cvxid.model.library import Library

    model = IdentifiedModel(ModelSpec(Library([parse_term("x"), parse_term("1")])), {"x''": 1.0, "x": 6.0, "1": -0.165})
    assert model.equation() == "1 x'' + 6 x - 0.165 = f", model.equation()
    assert model.equation_latex().endswith("+ 6\\,x - 0.165 = f"), model.equation_latex()


def test_the_first_compile_on_a_machine_is_said_once_on_a_terminal(monkeypatch):
    """A first run compiles the kernel for 20-30 s with nothing to show: numba's compile
    event of one of cvxid's kernels prints one line on a terminal's stderr, once; another
    library's compile, a redirected stderr and --quiet print nothing."""
    import io

    from numba.core.event import Event, EventStatus

    import cvxid.simulate as sim
    from cvxid.progress import set_quiet

    class Terminal(io.StringIO):
        def __init__(self, tty: bool):
            super().__init__()
            self.tty = tty

        def isatty(self):
            return self.tty

    def said(tty=True, quiet=False, dispatcher=sim._kernel):
        listener, stream = sim._FirstCompile(), Terminal(tty)
        monkeypatch.setattr(sim.sys, "stderr", stream)
        set_quiet(quiet)
        try:
            for _ in range(2):
                listener.on_start(Event("numba:compile", EventStatus.START, data={"dispatcher": dispatcher}))
        finally:
            set_quiet(False)
        return stream.getvalue()

    assert said().count("compiling the simulation kernel for this machine") == 1
    assert said(tty=False) == "" and said(quiet=True) == ""
    assert said(dispatcher=type("Other", (), {"py_func": len})()) == ""
