"""Paths, selection rules, k-fold, bootstrap and order search (issue: Algorithm 1)."""

import numpy as np
import pandas as pd
import pytest

from cvxid import CvxidError, CvxidWarning, Path, Problem
from cvxid.app.run import run
from cvxid.identify.bootstrap import Bootstrap, BootstrapSettings, bootstrap
from cvxid.regression.regression import Regression

from .conftest import ROOT, needs_paper_data


@pytest.fixture
def sparse(rng):
    n = 3000
    scales = np.array([1.0, 1e3, 1e-2, 5.0, 0.3, 1e2])  # badly scaled, as algebraic columns are
    P = rng.standard_normal((n, 6)) * scales
    truth = np.array([1.5, 0.0, -200.0, 0.0, 0.0, 0.08])
    p = P @ truth + 0.5 * rng.standard_normal(n)
    Pt = rng.standard_normal((n, 6)) * scales
    pt = Pt @ truth + 0.5 * rng.standard_normal(n)
    return P, p, Pt, pt, truth


def test_path_coefficients_frame_and_selection_rules(sparse):
    P, p, Pt, pt, truth = sparse
    prob = Problem.from_arrays(P, p, list("abcdef"))
    path = Path.compute(prob, np.logspace(-6, 1, 30), validate=lambda c: Pt @ c - pt)
    frame = path.coefficients
    assert isinstance(frame, pd.DataFrame) and frame.shape == (30, 6) and list(frame.columns) == list("abcdef")
    best = path.best("min")
    np.testing.assert_array_equal(best.support, truth != 0)
    one_se = path.best("1se")
    assert one_se.lam >= best.lam  # never less sparse than the minimum
    i = list(path.lambdas).index(one_se.lam)
    j = int(np.nanargmin(path.validation))
    assert path.validation[i] <= path.validation[j] + path.validation_se[j]
    with pytest.raises(CvxidError, match="unknown selection rule"):
        path.best("elbow")
    front = path.pareto  # the least training error for each number of terms: more terms, less error
    assert np.all(np.diff(front["train_mse"]) <= 1e-12)
    assert int((truth != 0).sum()) in front.index


def test_blocked_kfold_selects_the_true_support(sparse):
    P, p, _, _, truth = sparse
    path = Path.compute(Problem.from_arrays(P, p, list("abcdef")), np.logspace(-6, 1, 20), folds=5)
    assert np.all(np.isfinite(path.validation)) and np.all(path.validation_se > 0)
    np.testing.assert_array_equal(path.best("1se").support, truth != 0)


def test_weighted_bootstrap_equals_explicit_resample(sparse):
    P, p, Pt, pt, _ = sparse
    reg = Regression(P, p, tuple("abcdef"), ("library",) * 6, np.ones(6))
    counts = np.random.default_rng(3).multinomial(1500, np.full(len(p), 1 / len(p)))
    rows = np.repeat(np.arange(len(p)), counts)
    weighted = Problem.from_regression(reg, row_weights=counts).solve(1e-3)
    explicit = Problem.from_arrays(P[rows], p[rows], list("abcdef")).solve(1e-3)
    np.testing.assert_allclose(weighted.coefficients, explicit.coefficients, rtol=1e-6, atol=1e-9)


def test_bootstrap_is_reproducible_and_parallel_safe(sparse):
    P, p, Pt, pt, truth = sparse
    reg = Regression(P, p, tuple("abcdef"), ("library",) * 6, np.ones(6))
    kw = dict(lambdas=np.logspace(-5, 0, 12), validate=lambda c: Pt @ c - pt, show_progress=False)
    one = bootstrap(reg, settings=BootstrapSettings(6, 0.5, seed=7, n_jobs=1), **kw)
    two = bootstrap(reg, settings=BootstrapSettings(6, 0.5, seed=7, n_jobs=2), **kw)
    pd.testing.assert_frame_equal(one.coefficients, two.coefficients)
    other = bootstrap(reg, settings=BootstrapSettings(6, 0.5, seed=8, n_jobs=1), **kw)
    assert not one.coefficients.equals(other.coefficients)
    summary = one.summary()
    assert list(summary.columns) == ["mean", "std", "q2.5", "q97.5", "inclusion"]
    np.testing.assert_array_equal(summary["inclusion"].to_numpy() > 0.5, truth != 0)
    np.testing.assert_allclose(summary["mean"].to_numpy(), truth, rtol=0.02, atol=1e-3)


def test_the_samples_warnings_reach_the_caller_once_each_with_their_count(sparse):
    """A seventh outside check: each bootstrap worker printed its own warnings to stderr,
    raw (8 times the same).  Here a grid far below any term's exit (1e-15 … 1e-14) and a
    validation error that only falls as terms leave keep every sample's choice at an open
    top edge: one warning comes back, counting the samples, from worker processes too."""
    import warnings

    P, p, _, _, _ = sparse
    reg = Regression(P, p, tuple("abcdef"), ("library",) * 6, np.ones(6))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        bootstrap(reg, lambdas=[1e-15, 1e-14], validate=lambda c: c, show_progress=False,
                  settings=BootstrapSettings(6, 0.5, seed=7, n_jobs=2))
    said = [str(w.message) for w in caught if issubclass(w.category, CvxidWarning)
            and "bootstrap samples:" in str(w.message)]  # (beside the one that six samples are few)
    assert len(said) == 1 and said[0].startswith("6 of 6 bootstrap samples: the lambda rule chose the top of its "
                                                 "grid"), said


def test_out_of_bag_validation_without_a_test_set(sparse):
    P, p, _, _, truth = sparse
    boot = Bootstrap.of(Problem.from_arrays(P, p, list("abcdef")),
        samples=4, seed=1, lambdas=np.logspace(-5, 0, 10), show_progress=False
    )
    np.testing.assert_array_equal(boot.inclusion.to_numpy() == 1.0, truth != 0)


def test_bootstrap_settings_are_checked():
    with pytest.raises(CvxidError, match="fraction"):
        BootstrapSettings(10, 1.5)
    with pytest.raises(CvxidError, match="at least 2"):
        BootstrapSettings(1, 0.5)


@needs_paper_data
@pytest.mark.slow
def test_paper_algorithm1_picks_order_3_with_stable_inclusion():
    result = run(ROOT / "problems" / "paper_duffing_data.toml")
    assert result.order_search.best_order == 3
    # the rank-deficient columns of order 6 are said as the order search's, not as the order-3 model's
    deficient = [w for w in result.warnings if "rank-deficient" in w]
    assert deficient and all(w.startswith("the order search, order 6: ") for w in deficient), deficient
    inclusion = result.bootstrap.inclusion
    true_terms = {"x''", "x", "x'", "x^2 x'", "x'^3", "x^3", "x'''"}
    assert true_terms <= set(inclusion.index) and len(inclusion) > len(true_terms)
    for name, share in inclusion.items():
        if name in true_terms:
            assert share >= 0.9, name
        else:
            assert share <= 0.2, name


def test_clarabel_on_the_canonical_data_answers_as_cvxpy_does(sparse):
    """Each lambda solved by Clarabel on the data cvxpy canonicalised once equals cvxpy's
    own solve of the same problem (coefficients, status), signs held."""
    P, p, _, _, _ = sparse
    problem = Problem.from_arrays(P, p, list("abcdef"), nonnegative=("c", "e"))
    for lam in (1e-5, 1e-3, 3e-2, 0.5):
        ours = problem.solve(lam)
        problem.lam.value = lam
        problem.cvxpy.solve(solver="CLARABEL", warm_start=False)
        assert problem.cvxpy.status == "optimal" and ours.status == "optimal"
        theirs = problem._finish(lam, problem._full(problem.c.value), "optimal", 0.0)
        assert ours.objective <= theirs.objective * (1 + 1e-7)
        np.testing.assert_allclose(ours.scaled, theirs.scaled, atol=1e-6)
        assert ours.scaled[2] >= 0 and ours.scaled[4] >= 0


BOOTSTRAPPED = """
name = "bootstrapped"
[truth]
mass = 1.0
coefficients = {{ "x'" = 1.0, "x" = 39.0 }}
delay = {{ signal = "x", gain = 4.0, tau = 0.15 }}

[data.train.simulate]
duration = 10.0
dt = 1e-3
x0 = 0.05
seed = {seed}
noise = {{ output = 0.0005, input = 0.005 }}
input = [
  {{ kind = "sine", amplitude = 3.0, omega = 3.1 }},
  {{ kind = "sine", amplitude = 2.0, omega = 6.7, phase = 1.0 }},
  {{ kind = "sine", amplitude = 1.5, omega = 11.3, phase = 2.0 }},
]

[model.library]
terms = ["x", "x'"]

[model.delay]
signal = "x"
gain = 4.0
method = "exact"
tau_max = 0.3

[model.names]
k = "x"
c = "x'"

[fit]
bootstrap = {{ samples = 20, fraction = 0.5, seed = 0, resample = "{resample}" }}
"""


@pytest.mark.parametrize("seed", [3, 4])
def test_bootstrap_blocks_of_rows_give_intervals_that_cover(tmp_path, seed):
    """A tenth outside check: on sliding windows a bootstrap of single rows counted the same
    data many times, and held the exact delay at its estimate; a linear oscillator's every
    95 % interval missed the truth by 6-10 standard deviations, the delay's spread 0.
    Blocks of rows as long as the residual's correlation, each sample's delay profiled
    again, cover m, k, c and tau on seeds 3 and 4, where single rows miss k, their spread of
    k a fifth as wide or less.  (Not every seed: of seeds 0-9, 8 have every parameter
    covered; seed 1 misses tau, seed 9 m, c and tau — the equation error's bias from the
    noise on x, which no resampling sees.)"""
    truth = {"m": 1.0, "k": 39.0, "c": 1.0, "tau": 0.15}
    spreads = {}
    for resample in ("blocks", "rows"):
        spec = tmp_path / f"{resample}.toml"
        spec.write_text(BOOTSTRAPPED.format(seed=seed, resample=resample))
        spreads[resample] = run(spec).bootstrap.physical_summary()
    blocks, rows = spreads["blocks"], spreads["rows"]
    for name, value in truth.items():
        assert blocks.loc[name, "q2.5"] <= value <= blocks.loc[name, "q97.5"], name
    assert not rows.loc["k", "q2.5"] <= truth["k"] <= rows.loc["k", "q97.5"]
    assert blocks.loc["k", "std"] > 4 * rows.loc["k", "std"] and blocks.loc["tau", "std"] > 0


def test_bootstrap_blocks_take_the_same_stretch_of_every_equation():
    """Blocks span a share of the record: equations stacked with different row counts take
    the same stretch of time (a review: a 200-row equation got blocks of 4 rows where its
    residual spans 21), and a sample holds its size exactly (the last block cut)."""
    from cvxid.identify.bootstrap import block_counts

    counts = block_counts((1000, 200), 613, 0.105, np.random.default_rng(0))
    first, second = counts[:1000], counts[1000:]
    assert first.sum() == round(613 / 1200 * 1000) and second.sum() == round(613 / 1200 * 200)
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, second > 0, 0])))[::2]  # lengths of the drawn runs
    assert runs.max() >= 21  # (0.105 of 200 rows)
    same = (first.reshape(200, 5).sum(axis=1) > 0) == (second > 0)  # (a block's edge may round a row apart)
    assert same.mean() >= 0.95


def test_a_sample_that_leaves_a_column_without_a_row_is_drawn_again():
    """A review: a column nonzero on a stretch of the record only (a friction's column at
    rest elsewhere), and blocks long enough to miss it, stopped the whole run ("identically
    zero").  Such a sample is drawn again, and the ensemble still finds the coefficient."""
    rng = np.random.default_rng(5)
    n = 2000
    t = np.arange(n)
    a = np.sin(t / 40.0) + 0.1 * rng.standard_normal(n)
    b = np.where(t > 0.7 * n, np.cos(t / 25.0), 0.0)
    noise = np.convolve(rng.standard_normal(n + 599), np.ones(600) / 600, mode="valid")  # (correlated: long blocks)
    reg = Regression(np.c_[a, b], 1.5 * a + 2.0 * b + 0.01 * noise, ("a", "b"), ("library",) * 2, np.zeros(2))
    with pytest.warns(CvxidWarning, match=r"each sample holds about [\d.]+ independent stretches, so its spreads"):
        boot = bootstrap(reg, [1e-6], None, BootstrapSettings(20, 0.5, seed=0), show_progress=False)
    assert boot.share * n > 200 and len(boot.coefficients) == 20 and max(boot.kept) >= 20
    assert boot.summary().loc["b", "mean"] == pytest.approx(2.0, rel=0.01)
    assert all(((np.abs(b) > 0) & (c > 0)).any() for c in boot.draws((n,)))


def test_bootstrap_resample_is_checked(tmp_path):
    spec = tmp_path / "bad.toml"
    spec.write_text(BOOTSTRAPPED.format(seed=3, resample="pairs"))
    with pytest.raises(CvxidError, match=r"\[fit.bootstrap\] resample must be one of blocks, rows, got 'pairs'"):
        run(spec)


def test_each_samples_delay_does_not_depend_on_the_profiles_grid(tmp_path, monkeypatch):
    """A review: each sample's delay came from a parabola through three points of the
    41-point grid, up to a bootstrap standard deviation from a 401-point grid's.  Refined
    between the grid's neighbours as the estimate's own profile is, the grid no longer
    shows (measured: 7e-8 for a spread of 1.9e-4)."""
    import cvxid.app.run as run_module
    from cvxid.identify.bootstrap import with_delays

    seen = {}

    def spy(ensemble, regression_at, bounds, nonnegative=(), ties=(), **kw):
        seen.update(ensemble=ensemble, regression_at=regression_at, bounds=bounds)
        return with_delays(ensemble, regression_at, bounds, nonnegative, ties, **kw)

    monkeypatch.setattr(run_module, "with_delays", spy)
    spec = tmp_path / "blocks.toml"
    spec.write_text(BOOTSTRAPPED.format(seed=3, resample="blocks"))
    coarse = run(spec).bootstrap
    fine = with_delays(seen["ensemble"], seen["regression_at"], seen["bounds"], grid=401, show_progress=False)
    assert np.abs(coarse.taus - fine.taus).max() < 1e-3 * coarse.taus.std()


def test_the_bootstrap_spread_is_not_printed_beside_a_model_the_diagnosis_grew(tmp_path):
    """The bootstrap resamples the model the selection chose; where the diagnosis then adds
    an effect, its spreads (of the linear start: m 0.14, k 0.59) were printed as "boot std"
    beside the final model's estimates, the added friction's as "–"."""
    spec = (ROOT / "problems" / "hidden_friction.toml").read_text()
    spec = spec.replace('estimator = "stlsq"', 'estimator = "stlsq"\nbootstrap = { samples = 4 }')
    (tmp_path / "spec.toml").write_text(spec.replace('refine = "output_error"     #', 'refine = "none"     #'))
    result = run(tmp_path / "spec.toml")
    assert [s.added for s in result.refinement.steps] == ["coulomb"]
    text = result.summary()
    assert "boot std" not in text and "are of the equation-error model before the diagnosis added effects" in text
    assert "sign(x')" not in result.bootstrap.coefficients


def test_an_exact_delays_bootstrap_keeps_the_terms_most_samples_chose(tmp_path):
    """A check of the block bootstrap: with an exact delay the run refits the support the
    bootstrap gives, which was every term whose ensemble mean is nonzero — a term one block
    sample of ten picked stayed (duffing_delay_exact at order 3: 16 terms, a test fit of 89 %
    where the run without the bootstrap has 10 terms and 91 %; now 6 terms and 96.5 %).  The
    support is the terms at least half the samples chose."""
    spec = BOOTSTRAPPED.format(seed=3, resample="blocks").replace(
        'terms = ["x", "x\'"]', 'terms = ["x", "x\'", "x^2", "x^3", "x x\'"]\nselect = true')
    (tmp_path / "spec.toml").write_text(spec)
    result = run(tmp_path / "spec.toml")
    inclusion = result.bootstrap.inclusion
    assert ((inclusion > 0) & (inclusion < 0.5)).any()  # (some term a minority of samples chose)
    chosen = {n for n, share in inclusion.items() if share >= 0.5}
    assert set(result.model.support) == chosen


def test_a_bootstrap_of_few_samples_says_its_intervals_are_rough(sparse):
    """A check: samples = 2 printed a "95 % interval" of two values without a word."""
    P, p, _, _, _ = sparse
    reg = Regression(P, p, tuple("abcdef"), ("library",) * 6, np.ones(6))
    with pytest.warns(CvxidWarning, match="the bootstrap has 2 samples: its 95 % intervals are their extreme values"):
        bootstrap(reg, [1e-3], None, BootstrapSettings(2, 0.5, seed=0), show_progress=False)
