"""The examples in examples/ run (small settings) and tell their story."""

import json
import re
import runpy
import sys

import pandas as pd
import pytest

from .conftest import ROOT, SHARED_DATA

EXAMPLES = ROOT / "examples"


def run_example(name, monkeypatch, tmp_path, capsys, **env):
    monkeypatch.setenv("OUT", str(tmp_path))
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    monkeypatch.setattr(sys, "argv", [name])
    runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    return capsys.readouterr().out


def test_hidden_effect_story(monkeypatch, tmp_path, capsys):
    out = run_example("hidden_effect.py", monkeypatch, tmp_path, capsys)
    # the refinement table's one row: coulomb added, the test equation error falls 104x and
    # the free-run fit rises from 79 % to 98 % (measured)
    lines = out.split("Refinement")[1].splitlines()
    steps = [line.split() for line in lines if line.startswith("coulomb ")]
    assert len(steps) == 1
    header = lines[1].split()  # (term and group may print with spaces: read the numbers from the right)
    row = dict(zip(header[2:], steps[0][-(len(header) - 2):]))
    before, after, fit_before, fit_after = (float(row[k]) for k in ("test_mse_before", "test_mse_after", "fit_before",
                                                                    "fit_after"))
    assert before > 50 * after and fit_before < 85 and fit_after > 95
    for figure in ("1_linear_fit", "2_residual_vs_velocity", "3_error_falls", "4_final_fit"):
        assert (tmp_path / f"{figure}.png").stat().st_size > 10_000  # a drawn figure, not an empty file


@pytest.mark.slow
def test_paper_example_table(monkeypatch, tmp_path, capsys):
    out = run_example("paper_duffing.py", monkeypatch, tmp_path, capsys, SEEDS="1")
    # the tau error column (%), by method: the paper's truncation against cvxid's exact delay
    errors = {}
    for line in out.splitlines():
        for method in ("paper as published", "exact+oe"):
            if line.startswith(method):
                errors[method] = float(line[len(method):].split()[2])
    # measured on seed 1: the paper as published -21.6 %, exact delay + output error -0.69 %
    assert errors["paper as published"] < -15
    assert abs(errors["exact+oe"]) < 1.0


@pytest.mark.slow
@pytest.mark.skipif(not (SHARED_DATA / "silverbox_SNLS80mV.mat").is_file(), reason="Silverbox data absent")
def test_silverbox_diagnosis_finds_cubic_stiffness_and_a_damping(monkeypatch, tmp_path, capsys):
    """`cvxid run silverbox` on real data: the equation-error diagnosis adds cubic stiffness
    first, the diagnosis by simulation error a damping nonlinearity, and the model's free-run
    RMS error is at most the 0.28 mV target on both tests (measured 0.242 and 0.234 mV;
    0.307 and 0.317 mV without the simulation stage; the equation-error model of earlier
    sessions: 0.58 and 0.56 mV)."""
    out = run_example("silverbox.py", monkeypatch, tmp_path, capsys)
    refinement = out.split("Refinement")[1]
    assert refinement.split("\n")[3].startswith("cubic_stiffness")
    kept = [line.split()[0] for line in out.split("Diagnosis by simulation error")[1].splitlines()
            if line.endswith("True")]
    assert kept and all("damping" in name for name in kept), kept
    line = next(line for line in out.splitlines() if line.startswith("free-run RMS error"))
    errors = [float(v) for v in re.findall(r"([0-9.]+) mV", line)]
    assert len(errors) == 2 and max(errors) <= 0.28, line


def test_constraints_change_the_answer(monkeypatch, tmp_path, capsys):
    out = run_example("constraints.py", monkeypatch, tmp_path, capsys)
    rows = {line.split()[0]: line.split()[1:] for line in out.splitlines()[-6:]}
    truth, free, signed = (float(v) for v in rows["x'|x'|"])
    assert free < 0 and signed >= 0  # least squares returns a negative drag; the signs forbid it
    c_truth, c_free, c_signed = (float(v) for v in rows["x'"])
    assert abs(c_signed - c_truth) < abs(c_free - c_truth)


def test_lambda_path_example(monkeypatch, tmp_path, capsys):
    out = run_example("lambda_path.py", monkeypatch, tmp_path, capsys)
    stlsq = out.split("stlsq: Pareto front")[1]
    assert "min: lambda = 4.94, 7 terms: x'', x, x', x^3, x^2 x', x'^3, x'''" in stlsq
    assert (tmp_path / "path_lasso.png").is_file() and (tmp_path / "path_stlsq.png").is_file()


@pytest.mark.slow
def test_structure_from_noisy_x_meets_the_foundation_criterion(monkeypatch, tmp_path, capsys):
    # problems/duffing_delay.toml as shipped (seed 1): the 7-term support from noisy x only
    # (measured: m 0.03 %, k1 0.00 %, k3 0.15 %, c2 0.07 %, c3 0.24 %, c1 0.88 %, tau 0.46 %);
    # the paper's stlsq on the same data misses it
    run_example("structure_from_noisy_x.py", monkeypatch, tmp_path, capsys, SEEDS="1")
    table = pd.read_csv(tmp_path / "structure_from_noisy_x.csv").set_index("estimator")
    stepwise, stlsq = table.loc["stepwise_oe"], table.loc["stlsq"]
    assert bool(stepwise["true support"]) and not bool(stlsq["true support"])
    # the convex path (lasso, polish, pruning) finds it with the spec's Taylor delay; with an exact
    # delay, the linear terms kept (the default), this seed's lasso picks x^3 x' and x x'^3 for
    # x^2 x' and the pruning takes away the other three spurious terms; its exchange is not
    # tried, the model being within the noise level (14/16 seeds reach the support on
    # 2026-11-28: docs/benchmarks.md)
    assert table.loc["lasso + polish + pruning", "true support"]
    extra = {name: set(table.loc[name, "extra"].split()) for name in
             ("exact delay, lasso + polish, no pruning", "exact delay, lasso + polish + pruning")}
    assert extra["exact delay, lasso + polish + pruning"] < extra["exact delay, lasso + polish, no pruning"]
    for name, tolerance in {"m": 0.2, "k1": 0.2, "k3": 0.5, "c2": 0.5, "c3": 0.6, "c1": 1.5, "tau": 1.0}.items():
        assert abs(stepwise[f"{name} %"]) < tolerance, name


@pytest.mark.slow
def test_flexible_joint_example_accuracy_table(monkeypatch, tmp_path, capsys):
    out = run_example("flexible_joint.py", monkeypatch, tmp_path, capsys, SEEDS="1", DURATION="30")
    row = next(line.split() for line in out.splitlines() if line.startswith("1 "))
    added, tau_ee, ks_ee, tau, k_s = row[1], *map(float, row[2:6])
    assert added == "coulomb(theta)"
    # %, the output-error estimate (measured -0.044 %, -0.82 %; -0.05 %, -0.27 % before the integrator's friction
    # became continuous: the rig's friction is smooth, tanh(v / 0.05), the model's sticks, and k_s carries the mismatch)
    assert abs(tau) < 0.1 and abs(k_s) < 1.0
    assert abs(k_s) < abs(ks_ee) and abs(tau) < abs(tau_ee)  # the polish improves on the equation error


def test_sensor_fault_rules_on_random_systems(monkeypatch, tmp_path, capsys):
    """Two report seeds of examples/sensor_faults.py: every fault warned, no false alarm on
    the clean record, and gaps mend an outlier (on 10 seeds: better 10/10; a frozen stretch
    9/10; a clipped sensor only 6/10, so nothing is asserted for it)."""
    run_example("sensor_faults.py", monkeypatch, tmp_path, capsys, SEEDS="1000:1002")
    rows = pd.read_csv(tmp_path / "sensor_faults.csv")
    warned = rows.groupby("fault")["warned"].all()
    assert warned[["clipped", "frozen", "outlier"]].all() and not rows[rows["fault"] == "clean"]["warned"].any()
    fits = rows.pivot_table(index=["seed", "fault"], columns="faults", values="fit %")
    outlier, clean = fits.xs("outlier", level="fault"), fits.xs("clean", level="fault")
    assert (outlier["gap"] >= outlier["warn"]).all() and (outlier["gap"] > clean["warn"] - 0.5).all(), fits


def test_the_delays_warnings_on_random_systems(monkeypatch, tmp_path, capsys):
    """Report seed 1001 of examples/heldout_warnings.py: its delay (0.075 s) is not in its 8 s record; with
    the gain given the run says the delay is not determined (errors 230 and 444 %, it said nothing before), and
    with it estimated it never tells the user to raise tau_max where the gain trades with the stiffness."""
    run_example("heldout_warnings.py", monkeypatch, tmp_path, capsys, SEEDS="1001:1002")
    rows = pd.read_csv(tmp_path / "heldout_warnings.csv")
    given = rows[(rows["gain"] == "given") & (rows["effect"] != "quadratic_stiffness")]
    assert given["not determined"].all() and (given["tau error %"].abs() > 100).all() and given["covers"].all()
    assert not rows["raise tau_max"].any() and not rows["no feedback"].any()


@pytest.mark.slow
@pytest.mark.skipif(not (SHARED_DATA / "unbalanced_disk" / "training-val-test-data.npz").is_file(),
                    reason="unbalanced disk data absent")
def test_unbalanced_disk_diagnosis_finds_the_input_delay_and_friction(tmp_path):
    """`cvxid run unbalanced_disk` on real data: from gravity and viscous
    damping, the diagnosis adds an input delay then Coulomb friction (then, since the
    acceptance rule of issue 13, theta^2, which the simulation stage added before), and the
    polished model's free-run RMS error on the last 20 % is under the 0.05 rad target
    (measured 0.0274 rad with the theta^3 that the simulation stage adds since the
    integrator locates where sliding stops; 0.0327 rad without it before; 0.168 rad without
    the input delay)."""
    from cvxid.app.cli import main

    assert main(["run", "unbalanced_disk", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "result.json").read_text())
    assert [step["added"] for step in result["refinement"]][:2] == ["input_delay", "coulomb"]
    assert result["test_rms"] < 0.05
    assert 0.025 < result["input_delay"]["estimate"] < 0.05  # between one and two samples
    assert result["physical"]["sign(theta')"] > 0 and result["physical"]["sin(theta)"] > 0


@pytest.mark.slow
def test_fast_sampled_records_get_delay_intervals_of_the_standard_errors_width(monkeypatch, tmp_path, capsys):
    # report seed 1006, no hidden effect, sampled at 5 kHz: 5ca4d0c's interval was 0 ... 0.2404
    # (half-width 79 % of the delay) for an estimate 1.2 % off with a standard error of 2.6 %;
    # read against the profile's own least error it is 0.1418 ... 0.1679 (half-width 8.6 %)
    import cvxid.tools.heldout as heldout

    monkeypatch.setattr(heldout, "DT", heldout.DT)  # the example changes it: restored after the test
    run_example("fast_sampled_intervals.py", monkeypatch, tmp_path, capsys, SEEDS="1006:1007", EFFECTS="none")
    row = pd.read_csv(tmp_path / "fast_sampled_intervals.csv").iloc[0]
    assert bool(row["covers"]) and row["low"] > 0.1
    assert row["half-width %"] < 3 * row["1.96 se %"], row.to_dict()


def test_parameter_intervals_story(monkeypatch, tmp_path, capsys):
    # tuning seed 2, no hidden effect, the gain estimated: no Wald interval covers its truth,
    # every profile hull does (the same fit; tests/test_heldout.py has the warning)
    out = run_example("parameter_intervals.py", monkeypatch, tmp_path, capsys, SEEDS="2:3", EFFECTS="none")
    row = pd.read_csv(tmp_path / "parameter_intervals.csv").iloc[0]
    assert row["Wald covers %"] <= 25 and row["profile covers %"] == 100 and row["width ratio"] > 1
    assert "every parameter covered on 0 % and 100 % of systems" in out


def test_init_columns_story(monkeypatch, tmp_path, capsys):
    # tuning seeds 1 and 2 in five noise cases: init's spectrum rule names the position every
    # time, the noise level's ratio it replaced never (the force is the larger number)
    run_example("init_columns.py", monkeypatch, tmp_path, capsys, SEEDS="1:3")
    table = pd.read_csv(tmp_path / "init_columns.csv")
    assert len(table) == 10 and table["init picks the position"].all()
    assert not table["smoother by noise level"].any()


def test_coupled_heldout_story(monkeypatch, tmp_path, capsys):
    """examples/coupled_heldout.py, small: two drawn coupled systems, a hidden cubic
    stiffness (named, added alone, the fit rising to what the noise allows) and a control
    (nothing added); seed 100, measured."""
    out = run_example("coupled_heldout.py", monkeypatch, tmp_path, capsys, SEEDS="100:101",
                      EFFECTS="none,cubic_stiffness", N_JOBS="1")
    rows = {line.split()[0]: line.split() for line in out.splitlines()[2:4]}
    assert rows["none"][4] == "100.0"  # nothing added to the control
    cubic = rows["cubic_stiffness"]
    assert cubic[2:5] == ["100.0", "100.0", "100.0"]  # named first, added first, nothing else
    assert float(cubic[9]) >= float(cubic[10]) - 0.5  # the fit reaches what the noise allows
    assert "0 runs failed" in out


def test_a_missing_feedback_on_a_random_system(monkeypatch, tmp_path, capsys):
    """Report seed 1008 of examples/missing_delay.py at noise 0.002, 20 s: its model written
    without a delay gets the fed-back delay (tau -1.2 %, covered; before, nothing was added),
    the same system without the feedback gets no delay, and the friction is added where
    there is one."""
    run_example("missing_delay.py", monkeypatch, tmp_path, capsys, SEEDS="1008:1009", NOISE="0.002", DURATION="20")
    rows = pd.read_csv(tmp_path / "missing_delay.csv").set_index(["effect", "feedback"])
    fed = rows.loc[("none", "yes")]
    assert fed["delay added"] and not fed["input delay added"] and abs(fed["tau error %"]) < 5 and fed["covers"]
    assert not rows.xs("no (control)", level="feedback")["delay added"].any()
    assert rows.xs("coulomb", level="effect")["friction added"].all()


def test_records_rounded_to_coarse_steps_on_a_random_system(monkeypatch, tmp_path, capsys):
    """Report seed 1003 of examples/rounded_records.py: x rounded to steps whose error is
    0.5-4 % of its deviation, with and without a Coulomb friction.  Every fit reaches the
    noise's ceiling (before, the rounded records' noise read 0: fits of 48 % and -209 % at
    1 %), and the rounding is warned from 2 % on and not at 0.5 % (1 % is the threshold)."""
    run_example("rounded_records.py", monkeypatch, tmp_path, capsys, SEEDS="1003:1004")
    rows = pd.read_csv(tmp_path / "rounded_records.csv")
    assert (rows["test fit %"] > rows["noise allows %"] - 0.1).all(), rows
    share = rows["rounding share %"]
    assert rows.loc[share >= 2, "warned"].all() and not rows.loc[share <= 0.5, "warned"].any()


def test_the_same_system_in_micrometres_or_100_times_slower_gives_the_same_answer(tmp_path):
    """examples/units_and_time_scales.py, three of its rows through `cvxid init` and
    `cvxid run` (the delay searched over the reference's range in each record's time): the
    reference, its positions and forces in micrometres, and the plant 100 times slower give
    the same relative errors (in micrometres the fit's absolute gradient test stopped the
    polish at its start: the delay 3.3 %-points off; docs/benchmarks.md)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("units", ROOT / "examples" / "units_and_time_scales.py")
    units = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(units)
    rows = {name: units.one(tmp_path, name, *units.CASES[name])
            for name in ("reference (1 kHz, m)", "micrometres", "100 times slower")}
    reference = rows.pop("reference (1 kHz, m)")
    assert abs(reference["tau error %"]) < 15 and reference["tau covers"] and reference["m covers"]
    for name, row in rows.items():
        for key in ("m", "x'", "x", "tau"):
            assert row[f"{key} error %"] == pytest.approx(reference[f"{key} error %"], abs=0.1), (name, key)
            assert row[f"{key} covers"] == reference[f"{key} covers"], (name, key)


@pytest.mark.slow
def test_narrow_band_delays_find_their_basin_and_a_longer_delay(monkeypatch, tmp_path, capsys):
    """Tuning seeds 8 and 9 of examples/narrow_band_delays.py (regenerative chatter, the gain
    estimated).  Seed 9, the range holding the delay: its profile's lowest point (0.457 s)
    and the equation error's estimate (0.290) are aliases, and the true 0.205 s is found by
    the fits from the profile's basins (0.290 without them; measured +0.005 %, its interval
    covering).  Seed 8, the range stopping at 0.75 of the delay: the alias inside is
    reported, and the delay past the range that fits better is said, within 1 %."""
    run_example("narrow_band_delays.py", monkeypatch, tmp_path, capsys, SEEDS="8:10")
    rows = pd.read_csv(tmp_path / "narrow_band_delays.csv").set_index(["seed", "range"])
    for seed in (8, 9):
        held = rows.loc[(seed, "holds it")]
        assert abs(held["tau error %"]) < 0.1 and held["gain sign right"], seed
    assert bool(rows.loc[(9, "holds it"), "covers"])
    short = rows.loc[(8, "stops short")]
    assert not short["covers"] and bool(short["longer within 1 %"])


def test_given_values_wrong_masses_are_said_and_right_values_are_not(monkeypatch, tmp_path, capsys):
    """Tuning seed 0 of examples/given_values.py: the mass given 10 % high or low is said,
    as the value whose release fits best, its estimate's interval holding the truth; no
    right value (mass, gain, tie) is said alone.  A gain 20 % high and a tie 1.5 times too
    large are not said on this system: the stiffness and the delay absorb them within the
    noise (measured on 20 report-seed runs too: docs/benchmarks.md)."""
    run_example("given_values.py", monkeypatch, tmp_path, capsys, SEEDS="0:1")
    rows = pd.read_csv(tmp_path / "given_values.csv").set_index("case")
    for case in ("mass +10 %", "mass -10 %"):
        assert rows.loc[case, "wrong value said"] and rows.loc[case, "wrong fits best"], case
        assert rows.loc[case, "freed covers"], case
    for case in ("mass right", "gain right", "tie right", "gain +20 %", "tie x1.5"):
        assert not rows.loc[case, "right value said"] and not rows.loc[case, "wrong value said"], case
