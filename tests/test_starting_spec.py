"""`cvxid init DATA`: a commented starting spec that runs as written (docs/running.md)."""

import json

import numpy as np
import pytest

from cvxid import CvxidError
from cvxid.app.cli import main
from cvxid.app.starting_spec import detect_columns
from cvxid.spec.load import load_problem
from cvxid.tools.heldout import draw

from .test_sensor import SIMULATED, spec_text


def simulated_record():
    """hidden_friction's kind of record: x'' + 0.4 x' + 6 x + 0.8 sign(x') = f + 1.5 x(t - 0.15)."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "s.toml"
        spec.write_text(spec_text(SIMULATED).replace('coefficients = { "x\'" = 0.4, "x" = 6.0 }',
                                                             'coefficients = { "x\'" = 0.4, "x" = 6.0, '
                                                             '"sign(x\')" = 0.8 }'))
        return load_problem(spec).experiment("train")


def test_init_writes_a_spec_that_runs_as_written_and_finds_the_friction(tmp_path, capsys):
    record = simulated_record()
    np.savetxt(tmp_path / "rig.csv", np.column_stack([record.time, record.output("x"), record.input("f")]),
               delimiter=",", header="time,position,force", comments="")
    assert main(["init", str(tmp_path / "rig.csv"), "-o", str(tmp_path / "specs" / "rig.toml")]) == 0
    assert "wrote" in capsys.readouterr().out
    text = (tmp_path / "specs" / "rig.toml").read_text()
    assert 'file = "../rig.csv"' in text and 'output = { position = "position" }' in text
    assert "fraction = [0, 0.8]" in text and "fraction = [0.8, 1]" in text and "[diagnose]" in text
    assert '\nrefine = "output_error"' in text  # on as written; off here to keep the suite short (25 s more)
    quick = text.replace('\nrefine = "output_error"', "\n# refine")
    (tmp_path / "specs" / "rig.toml").write_text(quick)
    assert main(["run", str(tmp_path / "specs" / "rig.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["refinement"][0]["added"] == "coulomb"  # the missing friction, found from the start spec
    assert {"responses", "residuals", "refinement"} <= set(result["figures"])  # before/after, where, history
    assert result["test_fit_percent"] > 95
    # asked again, it keeps the user's file
    assert main(["init", str(tmp_path / "rig.csv"), "-o", str(tmp_path / "specs" / "rig.toml")]) == 2
    assert "exists; choose another -o or pass --force" in capsys.readouterr().err


def test_columns_found_by_their_shape_when_their_names_say_nothing(rng):
    t = np.arange(3000) * 0.01
    smooth = np.sin(0.7 * t) + 0.001 * rng.standard_normal(t.size)
    rough = np.sign(np.sin(3.1 * t)) + 0.3 * rng.standard_normal(t.size)
    columns = detect_columns({"c": rough, "a": t, "b": smooth})
    assert (columns.time, columns.output, columns.input) == ("a", "b", "c")
    assert "the lower spectrum" in columns.why and columns.dt == pytest.approx(0.01)


def test_a_noisy_measured_position_is_the_output_beside_a_clean_command():
    """Outside check: the noise level picked the clean command (its noise is nothing beside
    its spread) as the output; the spectrum above the noise floor picks the position."""
    t, x, _, f = draw(1, noise=0.0, duration=20.0).simulate("train")
    noisy = x + 0.01 * np.random.default_rng(3).standard_normal(x.size)
    columns = detect_columns({"time": t, "ch1": f, "ch2": noisy})
    assert (columns.output, columns.input) == ("ch2", "ch1")


def test_a_file_without_time_takes_dt_and_a_clear_error_otherwise(tmp_path, capsys):
    record = simulated_record()
    np.savez(tmp_path / "disk.npz", th=record.output("x"), u=record.input("f"))
    assert main(["init", str(tmp_path / "disk.npz"), "-o", str(tmp_path / "a.toml")]) == 2
    assert "no time column found (numeric columns: th, u): name it with --time, or give the sample step with --dt" in \
        capsys.readouterr().err
    assert main(["init", str(tmp_path / "disk.npz"), "-o", str(tmp_path / "a.toml"), "--dt", "0.001"]) == 0
    spec = load_problem(tmp_path / "a.toml")
    train = spec.experiment("train")
    assert train.dt == pytest.approx(0.001) and train.n == round(0.8 * record.n)
    assert spec.experiment("test").time[0] == pytest.approx(train.time[-1] + 0.001)


def test_dt_beside_a_time_column_must_agree_with_it(tmp_path, capsys):
    """A seventh outside check: ``--dt`` ten times off on a file with a time column
    ('stamp', found by its steady steps) was taken, and the spec said the file had no time
    column.  Ten times off is an error naming the column; the right step loads, and says
    the column agrees."""
    record = simulated_record()
    np.savetxt(tmp_path / "rig.csv", np.column_stack([record.time, record.output("x"), record.input("f")]),
               delimiter=",", header="stamp,pos_a,drive", comments="")
    assert main(["init", str(tmp_path / "rig.csv"), "-o", str(tmp_path / "a.toml"), "--dt", "0.01"]) == 2
    assert ("--dt 0.01 s disagrees with the file's time column 'stamp', whose samples are 0.001 (of its unit) "
            "apart: leave out --dt to read that column (--time stamp, with --time-unit if it does not count "
            "seconds), or correct --dt") in capsys.readouterr().err
    assert main(["init", str(tmp_path / "rig.csv"), "-o", str(tmp_path / "a.toml"), "--dt", "0.001"]) == 0
    text = (tmp_path / "a.toml").read_text()
    assert "the sample step given with --dt, which the column 'stamp' agrees with" in text
    assert "has no time column" not in text and load_problem(tmp_path / "a.toml").experiment("train").dt == 0.001
    # a column counting ms, or rounded stamps that repeat (the case --dt is for), is no disagreement
    for name, stamps in (("stamp", 1000 * record.time), ("time", np.round(record.time, 1))):
        np.savetxt(tmp_path / "rig.csv", np.column_stack([stamps, record.output("x"), record.input("f")]),
                   delimiter=",", header=f"{name},pos_a,drive", comments="")
        assert main(["init", str(tmp_path / "rig.csv"), "-o", str(tmp_path / "b.toml"), "--dt", "0.001",
                     "--force"]) == 0


@pytest.mark.parametrize("keys, message", [
    ('time = "t"\ndt = 0.01', "gives both time and dt"),
    ("fraction = [0.8, 0.2]", r"fraction must be \[start, end\] with 0 <= start < end <= 1"),
    ("dt = -1", r"\[data.train\] dt must be positive, got -1"),
])
def test_bad_data_keys_are_named(tmp_path, capsys, keys, message):
    from .conftest import cli_error

    (tmp_path / "d.csv").write_text("t,x,f\n" + "\n".join(f"{i * 0.01},{np.sin(i / 9)},{np.cos(i / 5)}"
                                                           for i in range(200)))
    text = f'[data.train]\nfile = "d.csv"\n{keys}\n[model.library]\nterms = ["x"]\n'
    import re

    assert re.search(message, cli_error(tmp_path, capsys, text))


@pytest.mark.parametrize("header, chosen", [
    ("time [s],force [N],position [m]", ("time [s]", "position [m]", "force [N]")),
    ("t,x,xdot,motor_cmd", ("t", "x", "motor_cmd")),
    ('t,u,x"1', ("t", 'x"1', "u")),
    ("t,u,θ", ("t", "θ", "u")),
])
def test_names_with_units_quotes_or_greek_give_a_spec_that_reads(tmp_path, header, chosen):
    """Units in brackets and words in names are read; a name that is no ASCII identifier is
    quoted in the spec and the coordinate is called x (a quote or a θ made invalid TOML)."""
    import csv

    record = simulated_record()
    names = next(csv.reader([header]))
    columns = {"t": record.time, "x": record.output("x"), "u": record.input("f")}
    if len(names) == 4:  # t, x, its derivative (not used), the command
        data = [columns["t"], columns["x"], np.gradient(columns["x"], record.dt), columns["u"]]
    else:  # time, input, output
        data = [columns["t"], columns["u"], columns["x"]]
    with open(tmp_path / "rig.csv", "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(names)
        writer.writerows(np.column_stack(data).tolist())
    assert main(["init", str(tmp_path / "rig.csv"), "-o", str(tmp_path / "rig.toml")]) == 0
    spec = load_problem(tmp_path / "rig.toml")
    table = spec.data["train"]
    assert (table["time"], *table["output"].values(), *table["input"].values()) == chosen
    assert np.allclose(spec.experiment("train").output(spec.model.coordinate)[:5], record.output("x")[:5])


@pytest.mark.parametrize("damage, said", [
    (lambda rows: rows[:8], "only 6 samples; at least 20 are needed"),  # (80 % of 8 trains)
    (lambda rows: np.vstack([rows[:300], rows[299:]]), "does not increase from data row 300 to 301 (0.299, then "
                                                      "0.299): sort the file and remove repeated rows"),
    # an outside check: a logger's clock that restarted was to be sorted, interleaving two records
    (lambda rows: np.vstack([rows[:1500], rows[:1500]]), "the clock goes back by 1.499 s there, as a logger's that "
                                                         "restarted: the file holds two records; cut it there"),
    # the re-review: one stamp far off both its neighbours is a corrupted stamp, not a restart
    (lambda rows: np.vstack([rows[:1000], [[400.0, 0.0, 0.0]], rows[1001:]]), "the stamp 400 is out of line with "
                                                                              "both its neighbours"),
    (lambda rows: rows[:0], "the file has 0 data rows"),
    (lambda rows: rows[:1], "the file has 1 data row: nothing to identify"),
    (lambda rows: np.column_stack([rows[:, :2], 0 * rows[:, 2]]), "input 'f' is constant"),  # a free decay
])
def test_init_refuses_a_record_cvxid_run_would_refuse(tmp_path, capsys, damage, said):
    """Outside check: init wrote a spec it said "runs as written" for a file that cvxid run
    then refused; now it reads the records as the run will and writes nothing."""
    t = np.arange(2000) * 1e-3
    rows = damage(np.column_stack([t, np.sin(3 * t), np.cos(7 * t)]))
    np.savetxt(tmp_path / "r.csv", rows, delimiter=",", header="t,x,f", comments="")
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml")]) == 2
    assert said in capsys.readouterr().err and not (tmp_path / "r.toml").exists()


def test_init_names_a_text_column(tmp_path, capsys):
    (tmp_path / "r.csv").write_text("t,x,f\n" + "".join(f"{i * 0.01},{'abc' if i % 2 else i},{i}\n"
                                                          for i in range(100)))
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml")]) == 2
    assert "not numeric (text, or mostly empty): x" in capsys.readouterr().err


@pytest.mark.parametrize("time_unit, slow, expected", [
    (1.0, 1.0, (0.5, 0.55)),      # an ordinary plant (median period about 4 s): about the documented 0.5 s
    (1.0, 10.0, (4.0, 6.0)),      # ten times slower: an eighth of its median period, where 0.5 s was written
    (1e3, 1.0, (400.0, 600.0)),   # the ordinary plant timed in ms: the same eighth of its period, in ms
])
def test_init_searches_delays_on_the_record_s_own_time_scale(tmp_path, time_unit, slow, expected):
    """An outside check: for a slow plant (period 21 s, delay 2 s) `cvxid init` wrote
    tau_max = 0.5 and the run returned a delay pinned under it with a wrong mass; for a
    record timed in ms it wrote a spec the run refused.  The longest delay searched is an
    eighth of the period of the output's median frequency (at least 0.5, at most a tenth of
    the record), in the time column's unit."""
    record = simulated_record()
    t = record.time * slow * time_unit
    np.savetxt(tmp_path / "rig.csv", np.column_stack([t, record.output("x"), record.input("f")]),
               delimiter=",", header="t,x,f", comments="")
    assert main(["init", str(tmp_path / "rig.csv"), "-o", str(tmp_path / "rig.toml")]) == 0
    spec = load_problem(tmp_path / "rig.toml")
    tau_max = spec.model.delay.tau_max
    assert expected[0] <= tau_max <= expected[1], tau_max
    assert tau_max > 0.15 * slow * time_unit  # the delay of the record's system lies inside the range searched


@pytest.mark.parametrize("header, arguments", [
    ("time_ms,x,f", []),                 # the unit read off the column's name
    ("t [ms],x,f", []),
    ("t,x,f", ["--time-unit", "ms"]),    # or given
])
def test_init_reads_a_time_column_in_milliseconds_as_seconds(tmp_path, header, arguments):
    """A fourth outside check: a record timed in ms was labelled in seconds ("dt = 1 s",
    "95 % interval 0 … 375 s") and its delay range was in ms.  A time column whose name
    says ms (or --time-unit ms) is written as ``time_unit = "ms"``: the run reads the same
    record, in seconds, as the record timed in seconds, and searches the same delays."""
    record = simulated_record()
    np.savetxt(tmp_path / "ms.csv", np.column_stack([record.time * 1e3, record.output("x"), record.input("f")]),
               delimiter=",", header=header, comments="")
    assert main(["init", str(tmp_path / "ms.csv"), "-o", str(tmp_path / "ms.toml"), *arguments]) == 0
    text = (tmp_path / "ms.toml").read_text()
    assert 'time_unit = "ms"' in text and "dt = 0.001 s" in text
    spec = load_problem(tmp_path / "ms.toml")
    train = spec.experiment("train")
    np.testing.assert_allclose(train.time, record.time[:train.n], rtol=0, atol=1e-12)
    assert 0.5 <= spec.model.delay.tau_max <= 0.55  # as for the record timed in seconds (above)


def test_a_time_unit_beside_a_sample_step_or_unknown_is_named(tmp_path, capsys):
    _base_csv(tmp_path / "r.csv")
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml"), "--dt", "0.001",
                 "--time-unit", "ms"]) == 2
    assert "--time-unit is the time column's unit, and --dt is in seconds" in capsys.readouterr().err
    spec = tmp_path / "s.toml"
    for table, said in (('time = "t"\ntime_unit = "fortnights"', "time_unit must be one of s, ms, us, min, h"),
                        ('dt = 0.001\ntime_unit = "ms"', "time_unit is the unit of a file's time column")):
        spec.write_text(f'[model]\n[data.train]\nfile = "r.csv"\n{table}\noutput = "x"\ninput = "f"\n')
        with pytest.raises(CvxidError, match=said):
            load_problem(spec)


def _base_csv(path, header="t,x,f", rows=2000, extra=None):
    """A small record (t, x, f and ``extra`` columns) written with ``header``."""
    t = np.arange(rows) * 1e-3
    columns = [t, np.sin(3 * t), np.cos(7 * t), *(extra or [])]
    np.savetxt(path, np.column_stack(columns), delimiter=",", header=header, comments="")


@pytest.mark.parametrize("arguments, said", [
    (["--dt", "-1"], "--dt must be the sample step, a positive number of seconds, got -1"),
    (["--dt", "nan"], "--dt must be the sample step, a positive number of seconds, got nan"),
    (["--dt", "0"], "--dt must be the sample step, a positive number of seconds, got 0"),
    (["--time", "t", "--dt", "0.001"], "give the time column (--time t) or the sample step (--dt 0.001), not both"),
    (["--time", "x"], "the time column 'x' does not increase from data row"),
])
def test_init_refuses_a_sample_step_that_is_not_one(tmp_path, capsys, arguments, said):
    """A fourth outside check: a zero, negative or NaN step, or a time column that does not
    increase, ended in a ZeroDivisionError or scipy's "sampling frequency must be positive"
    traceback; --dt beside --time was dropped without a word."""
    _base_csv(tmp_path / "r.csv")
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml"), *arguments]) == 2
    assert said in capsys.readouterr().err and not (tmp_path / "r.toml").exists()


def test_init_names_rounded_epoch_stamps(tmp_path, capsys):
    """Epoch seconds written with 8 significant digits repeat: a clear error (it divided by
    a zero step)."""
    t = 1.7e9 + np.arange(2000) * 1e-3
    np.savetxt(tmp_path / "r.csv", np.column_stack([t, np.sin(3 * t), np.cos(7 * t)]), delimiter=",",
               header="t,x,f", comments="", fmt="%.8g")
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml")]) == 2
    assert "the time column 't' does not increase from data row 1 to 2 (1700000000, then 1700000000)" in \
        capsys.readouterr().err


def test_init_asks_which_input_when_two_columns_are_named_like_one(tmp_path, capsys):
    """A fourth outside check: with a force f and a reference u, init took u by its rank in
    its list of names and the run diverged; now it asks."""
    t = np.arange(2000) * 1e-3
    _base_csv(tmp_path / "r.csv", "t,x,f,u", extra=[np.sin(0.3 * t)])
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml")]) == 2
    assert "the columns f, u are each named like an input: say which one with --input" in capsys.readouterr().err
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml"), "--input", "f"]) == 0
    assert load_problem(tmp_path / "r.toml").data["train"]["input"] == {"f": "f"}


def test_init_refuses_a_file_without_a_header_line(tmp_path, capsys):
    """A fourth outside check: the first data row became the column names, without a word."""
    _base_csv(tmp_path / "r.csv", header="")
    text = (tmp_path / "r.csv").read_text().lstrip("\n")
    (tmp_path / "r.csv").write_text(text)
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml")]) == 2
    assert "is numbers, not column names: add a header line that names the columns" in capsys.readouterr().err


def test_init_names_the_row_of_a_bad_cell(tmp_path, capsys):
    """A fourth outside check: one cell "ERR" made the whole column "not numeric" with no row."""
    _base_csv(tmp_path / "r.csv")
    lines = (tmp_path / "r.csv").read_text().splitlines()
    lines[7] = lines[7].rsplit(",", 1)[0] + ",ERR"  # the 7th data row's f
    (tmp_path / "r.csv").write_text("\n".join(lines) + "\n")
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml")]) == 2
    assert "f (data row 7: 'ERR')" in capsys.readouterr().err


def test_init_loads_missing_samples_as_gaps(tmp_path):
    """A fourth outside check: a record with empty cells got "load with gaps = true" from
    init, which had no way to say it and wrote nothing; now it writes the key."""
    _base_csv(tmp_path / "r.csv")
    lines = (tmp_path / "r.csv").read_text().splitlines()
    for row in range(600, 640):  # 40 samples of x and f lost
        lines[row] = lines[row].split(",")[0] + ",,"
    (tmp_path / "r.csv").write_text("\n".join(lines) + "\n")
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml")]) == 0
    text = (tmp_path / "r.toml").read_text()
    assert text.count("\ngaps = true") == 2 and "loaded as gaps" in text
    train = load_problem(tmp_path / "r.toml").experiment("train")
    assert train.gaps and np.isnan(train.output("x")).sum() == 40 and len(train.segments()) == 2


def test_init_loads_rows_missing_from_the_time_column_as_gaps(tmp_path):
    """A fourth outside check: a record with rows lost got advice (split it) that a spec
    cannot follow; init now writes gaps = true and the rows become gaps."""
    _base_csv(tmp_path / "r.csv")
    lines = (tmp_path / "r.csv").read_text().splitlines()
    (tmp_path / "r.csv").write_text("\n".join(lines[:601] + lines[701:]) + "\n")  # 100 data rows lost
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml")]) == 0
    text = (tmp_path / "r.toml").read_text()
    assert "100 rows missing from the time column, loaded as gaps" in text and text.count("\ngaps = true") == 2
    train = load_problem(tmp_path / "r.toml").experiment("train")
    assert train.gaps and np.isnan(train.output("x")).sum() == 100


@pytest.mark.parametrize("names, chosen", [
    (("time", "theta", "theta_dot", "torque"), ("theta", "torque")),
    (("t", "angle", "angle_rate", "voltage"), ("angle", "voltage")),
])
def test_a_whole_name_goes_before_a_word_of_one(names, chosen):
    """A review of the ambiguity error: theta_dot (a word 'theta') beside theta made a file
    that init read before an error; a whole name is taken before a word of one."""
    t = np.arange(3000) * 1e-3
    rng = np.random.default_rng(0)
    columns = dict(zip(names, [t, np.sin(0.7 * t) + 1e-3 * rng.standard_normal(t.size), np.cos(0.7 * t),
                               np.sign(np.sin(3 * t)) + 0.3 * rng.standard_normal(t.size)]))
    found = detect_columns(columns)
    assert (found.output, found.input) == chosen


def test_init_reads_pandas_default_header(tmp_path):
    """A review of the headerless check: pandas' to_csv of an unnamed frame writes the header
    0,1,2, which names the columns (it was read before and must still be)."""
    import pandas as pd

    t = np.arange(2000) * 1e-3
    pd.DataFrame(np.column_stack([t, np.sin(3 * t), np.cos(7 * t)])).to_csv(tmp_path / "r.csv", index=False)
    assert main(["init", str(tmp_path / "r.csv"), "-o", str(tmp_path / "r.toml"), "--time", "0", "--output", "1",
                 "--input", "2"]) == 0
