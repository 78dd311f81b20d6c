"""Experiment validation and loaders."""

import warnings

import numpy as np
import pytest
from scipy.io import savemat

from cvxid import CvxidError, CvxidWarning, Experiment, load

T = np.arange(100) * 0.01


def make(**over):
    kw = dict(time=T, outputs={"x": np.sin(T)}, inputs={"f": np.cos(T)}, name="e")
    kw.update(over)
    return Experiment(**kw)


def test_valid_experiment_prints_its_shape():
    e = make()
    assert e.n == 100 and e.dt == pytest.approx(0.01)
    assert "100 samples" in repr(e) and "outputs: x" in repr(e)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(outputs={"x": np.r_[np.sin(T[:-1]), np.nan]}), "NaN/inf value"),
        (dict(inputs={"f": np.r_[np.inf, np.cos(T[1:])]}), "the first at sample 0"),
        (dict(outputs={"x": np.sin(T[:-3])}), "same length"),
        (dict(time=np.r_[T[:50], T[49:99]]), "not strictly increasing"),
        (dict(time=np.r_[T[:50], T[50:] + 0.003]), "not uniformly sampled"),
        (dict(time=T[:5], outputs={"x": T[:5]}, inputs={"f": T[:5]}), "at least 20"),
        (dict(outputs={}), "no output"),
        (dict(outputs={"x": np.ones((100, 2))}), "1-D array"),
        (dict(outputs={"x": ["a"] * 100}), "not numeric"),
    ],
)
def test_bad_input_is_named(change, message):
    with pytest.raises(CvxidError, match=message):
        make(**change)


def test_csv_loader_reads_named_columns(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("t,pos,force\n" + "\n".join(f"{a},{b},{c}" for a, b, c in zip(T, np.sin(T), np.cos(T))))
    e = load(path, time="t", outputs={"x": "pos"}, inputs={"f": "force"})
    np.testing.assert_allclose(e.output("x"), np.sin(T))
    with pytest.raises(CvxidError, match="no column named 'disp'.*available: force, pos, t"):
        load(path, time="t", outputs={"x": "disp"}, inputs={"f": "force"})


def test_mat_loader_reads_named_variables(tmp_path):
    path = tmp_path / "d.mat"
    savemat(path, {"t": T[:, None], "x_tr": np.sin(T)[:, None], "F": np.cos(T)[None, :]})
    e = load(path, time="t", outputs={"x": "x_tr"}, inputs={"f": "F"})
    np.testing.assert_allclose(e.input("f"), np.cos(T))
    with pytest.raises(CvxidError, match="no variable named 'v'"):
        load(path, time="t", outputs={"x": "v"}, inputs={"f": "F"})


def test_loader_errors(tmp_path):
    with pytest.raises(CvxidError, match="not found"):
        load(tmp_path / "missing.csv", time="t", outputs={"x": "x"}, inputs={})
    bad = tmp_path / "d.txt"
    bad.write_text("1")
    with pytest.raises(CvxidError, match="unknown data format"):
        load(bad, time="t", outputs={"x": "x"}, inputs={})
    junk = tmp_path / "junk.mat"
    junk.write_bytes(b"not a mat file at all")
    with pytest.raises(CvxidError, match="cannot be read as a MATLAB file"):
        load(junk, time="t", outputs={"x": "x"}, inputs={})


def test_npz_and_dataframe_loaders(tmp_path):
    import pandas as pd

    from cvxid import from_frame

    path = tmp_path / "d.npz"
    np.savez(path, t=T, x=np.sin(T), f=np.cos(T))
    e = load(path, time="t", outputs={"x": "x"}, inputs={"f": "f"})
    np.testing.assert_allclose(e.output("x"), np.sin(T))
    frame = pd.DataFrame({"time": T, "pos": np.sin(T), "u": np.cos(T)})
    e2 = from_frame(frame, time="time", outputs={"x": "pos"}, inputs={"f": "u"})
    np.testing.assert_allclose(e2.input("f"), np.cos(T))
    with pytest.raises(CvxidError, match="no column named 'v'"):
        from_frame(frame, time="time", outputs={"x": "v"}, inputs={})


def test_a_time_column_in_milliseconds_reads_as_seconds_with_its_velocities():
    """``time_unit = "ms"``: the time (epoch stamps too, their steps kept) in seconds, a
    measured velocity per ms converted to per second; a unit cvxid does not know is named."""
    import pandas as pd

    from cvxid import from_frame

    ms = 1.7e12 + np.arange(T.size) * 1e3 * (T[1] - T[0])  # epoch milliseconds
    frame = pd.DataFrame({"t": ms, "x": np.sin(T), "v": np.cos(T) * 1e-3, "f": np.cos(T)})
    e = from_frame(frame, time="t", outputs="x", inputs="f", velocities="v", time_unit="ms")
    np.testing.assert_allclose(np.diff(e.time), np.diff(T), rtol=0, atol=5e-7)  # (epoch seconds' own rounding)
    assert e.time[0] == pytest.approx(1.7e9) and e.time[-1] - e.time[0] == pytest.approx(T[-1], abs=5e-7)
    np.testing.assert_allclose(e.velocities["x"], np.cos(T), rtol=1e-12)
    with pytest.raises(CvxidError, match="time_unit must be one of s, ms, us, min, h .* got 'msec'"):
        from_frame(frame, time="t", outputs="x", inputs="f", time_unit="msec")
    jitter = frame.assign(t=np.arange(T.size) * 10.0 + np.random.default_rng(0).uniform(-0.03, 0.03, T.size))
    with pytest.warns(CvxidWarning, match=r"of the mean step 0.0100\d* s; .*largest time shift [0-9.e-]+ s"):
        from_frame(jitter, time="t", outputs="x", inputs="f", time_unit="ms")  # said in seconds (a review: in ms)


def test_gaps_split_into_segments_and_restart_the_integrals():
    from cvxid.model.equation import ModelSpec
    from cvxid.model.library import Library
    from cvxid.model.terms import parse_term
    from cvxid.regression.builder import RegressionBuilder

    t = np.arange(400) * 0.01
    x, f = np.sin(1.3 * t), np.cos(0.7 * t)
    x_gap = x.copy()
    x_gap[150:160] = np.nan
    with pytest.raises(CvxidError, match="gaps = true"):
        Experiment(t, {"x": x_gap}, {"f": f})
    e = Experiment(t, {"x": x_gap}, {"f": f}, gaps=True)
    parts = e.segments()
    assert [p.n for p in parts] == [150, 240]
    model = ModelSpec(Library([parse_term("x"), parse_term("x'")]))
    with_gap = RegressionBuilder(model, e, "savgol", window="record").at(None)
    stacked = RegressionBuilder(model, parts, "savgol", window="record").at(None)
    np.testing.assert_array_equal(with_gap.P, stacked.P)
    assert with_gap.shape[0] == 390  # the 10 missing samples are not interpolated
    windowed = RegressionBuilder(model, e, "savgol", window=0.3).at(None)  # no window straddles the gap
    assert windowed.shape[0] == sum(p.n - 31 + 1 for p in parts)  # 31-sample windows, one per shift


def test_logger_jitter_is_resampled_with_a_warning_and_real_non_uniformity_refused(rng):
    """Steps of 0.00100003 s (as a logger writes them) are jitter: the record is put on the
    uniform grid of the mean step and the warning says by how much; a step 2 % off is
    refused with what to do."""
    t = np.arange(4000) * 1e-3
    jittered = t + rng.uniform(-3e-8, 3e-8, t.size)
    with pytest.warns(CvxidWarning, match=r"jitter by up to 0.00\d+ % of the mean step 0.001 s; the record was "
                                          r"resampled onto the uniform grid \(largest time shift [0-9.e-]+ s"):
        e = Experiment(jittered, {"x": np.sin(3 * jittered)}, {"f": np.cos(jittered)})
    assert np.ptp(np.diff(e.time)) < 1e-15
    assert np.max(np.abs(e.output("x") - np.sin(3 * e.time))) < 1e-9  # the signal moved with its time
    off = t.copy()
    off[2000:] += 2e-5  # one step 2 % long
    with pytest.raises(CvxidError, match=r"2 % off; up to 1 % is taken as logger jitter\): resample"):
        Experiment(off, {"x": np.sin(t)}, {"f": np.cos(t)})


def test_a_csv_with_logger_jitter_runs_end_to_end(tmp_path):
    """`cvxid run` on a CSV whose time column jitters gives the model of the clean record
    (within 1e-4) and says it resampled."""
    import json

    import cvxid
    from cvxid.app.cli import main

    from .test_sensor import SIMULATED, spec_text

    (tmp_path / "simulated.toml").write_text(spec_text(SIMULATED))
    train = cvxid.load_problem(tmp_path / "simulated.toml").experiment("train")
    jitter = np.random.default_rng(7).uniform(-3e-8, 3e-8, train.n)
    coefficients = {}
    for name, time in (("clean", train.time), ("jittered", train.time + jitter)):
        np.savetxt(tmp_path / "train.csv", np.column_stack([time, train.output("x"), train.input("f")]),
                   delimiter=",", header="t,x,f", comments="", fmt="%.10g")
        (tmp_path / "spec.toml").write_text(spec_text('file = "train.csv"'))
        assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / name)]) == 0
        result = json.loads((tmp_path / name / "result.json").read_text())
        coefficients[name] = result["physical"]
        assert any("jitter" in w for w in result["warnings"]) == (name == "jittered")
    for key, value in coefficients["clean"].items():
        assert coefficients["jittered"][key] == pytest.approx(value, rel=1e-4, abs=1e-6), key


def test_csv_with_semicolons_decimal_commas_tabs_or_a_units_row_reads_the_same(tmp_path):
    """A spreadsheet's export: semicolons with decimal commas, tabs, or a row of units
    under the header (skipped with a warning); each used to be an error that did not name
    its cause ("no column named 't'; available: t;x;f", "not numeric ... 'm'").  Comment
    lines (#) at the top are skipped, and a commented header (numpy's) is the header."""
    import warnings

    from cvxid import CvxidWarning
    from cvxid.data.experiment import load

    t = np.arange(200) * 0.01
    x, f = np.sin(t), np.cos(3 * t)
    rows = [f"{a:.6f},{b:.6f},{c:.6f}" for a, b, c in zip(t, x, f)]
    variants = {
        "comma.csv": "t,x,f\n" + "\n".join(rows),
        "semicolon.csv": "t;x;f\n" + "\n".join(r.replace(",", ";").replace(".", ",") for r in rows),
        "tab.csv": "t\tx\tf\n" + "\n".join(r.replace(",", "\t") for r in rows),
        "units.csv": "t,x,f\ns,m,N\n" + "\n".join(rows),
        # an outside check: with a units row, read with commas first, it could not be parsed at all
        "semicolon_units.csv": "t;x;f\ns;m;N\n" + "\n".join(r.replace(",", ";").replace(".", ",") for r in rows),
        "semicolon_point.csv": "t;x;f\n" + "\n".join(r.replace(",", ";") for r in rows),
        # a fifteenth outside check: a logger's comment lines above the header ended in pandas' tokenizer message;
        # numpy's savetxt writes its header as a comment, which became a time column named "# t"
        "comments.csv": "# logger v2\n# rate 100 Hz\nt,x,f\n" + "\n".join(rows),
        "savetxt.csv": "# t,x,f\n" + "\n".join(rows),
        "comments_units.csv": "# logger v2\nt,x,f\ns,m,N\n" + "\n".join(rows),
        "comments_semicolon.csv": "# notes; more\n#t;x;f\n" + "\n".join(r.replace(",", ";").replace(".", ",")
                                                                           for r in rows),
    }
    for name, text in variants.items():
        (tmp_path / name).write_text(text + "\n")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            e = load(tmp_path / name, "t", "x", "f")
        assert e.n == 200 and np.allclose(e.output("x"), x, atol=1e-6) and np.allclose(e.input("f"), f, atol=1e-6)
        said = [str(w.message) for w in caught if issubclass(w.category, CvxidWarning)]
        assert any("(s, m, N) is text in every column; it was read as units and skipped" in m for m in said) == \
            ("units" in name), (name, said)


def test_a_large_csv_is_read_in_chunks_to_the_same_columns(tmp_path, monkeypatch):
    """Above LARGE_CSV bytes the file is parsed a chunk of rows at a time (the whole-file
    parser's buffers are three times the numbers): the same columns, with a units row or
    semicolons and decimal commas still understood."""
    import cvxid.data.experiment as experiment

    rows = [f"{i * 0.001:.3f},{np.sin(i / 50):.6f},{np.cos(i / 70):.6f}\n" for i in range(5000)]
    (tmp_path / "units.csv").write_text("t,x,f\ns,m,N\n" + "".join(rows))
    (tmp_path / "semicolon.csv").write_text("t;x;f\n" + "".join(r.replace(",", ";").replace(".", ",") for r in rows))
    with pytest.warns(CvxidWarning, match="read as units and skipped"):
        whole = experiment._csv_columns(tmp_path / "units.csv")
    monkeypatch.setattr(experiment, "LARGE_CSV", 1000)
    monkeypatch.setattr(experiment, "CSV_CHUNK", 777)
    for name in ("units.csv", "semicolon.csv"):
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            chunked = experiment._csv_columns(tmp_path / name)
        assert any("read as units" in str(w.message) for w in said) == (name == "units.csv")
        assert list(chunked) == ["t", "x", "f"] and all(np.array_equal(chunked[c], whole[c]) for c in whole)
    assert whole["x"].size == 5000 and whole["x"][100] == pytest.approx(np.sin(2.0), abs=1e-6)


def test_a_csv_separator_is_the_one_that_splits_every_row_alike(tmp_path):
    """A stranger's files: a semicolon file whose first 150 rows hold only whole numbers
    (time in samples, a record at rest: the decimal comma comes later), a comma inside a
    column's name under semicolons or tabs, a byte-order mark, a blank first line.  Each
    read to the same numbers (the first failed on the decimal comma, the second and third
    split the header wrongly, the last was an error)."""
    from cvxid.data.experiment import _csv_columns

    x = np.r_[np.zeros(150), 0.5 * np.sin(np.arange(150) / 9.0)]
    rows = [(i, v, -v) for i, v in enumerate(x)]

    def text(sep, decimal=".", header="t{s}x{s}force, N"):
        body = [sep.join(f"{c:.4f}".rstrip("0").rstrip(".") if c != 0 else "0" for c in r) for r in rows]
        return header.format(s=sep) + "\n" + "\n".join(b.replace(".", decimal) for b in body) + "\n"

    files = {"late_comma.csv": text(";", ",", "t;x;force"), "semicolon_name.csv": text(";", ","),
             "tab_name.csv": text("\t"), "bom.csv": "\ufeff" + text(";", ",", "t;x;force"),
             "blank.csv": "\n" + text(",", ".", "t,x,force")}
    for name, content in files.items():
        (tmp_path / name).write_text(content, encoding="utf-8")
        columns = _csv_columns(tmp_path / name)
        force = "force, N" if "name" in name else "force"
        assert list(columns) == ["t", "x", force], (name, list(columns))
        assert np.allclose(columns["x"], np.round(x, 4)) and np.allclose(columns[force], -np.round(x, 4)), name


def test_epoch_stamps_that_jitter_by_their_rounding_alone_are_not_resampled():
    """A fourth outside check: epoch seconds (1.7e9 s, 2.4e-7 s apart in a float) "jittered"
    by 0.017 % of a 1 ms step; the record was resampled with a warning, and each part cut
    from the resampled grid was warned about again (the same grid, "largest time shift
    0 s").  A time on its uniform grid to a few units of its last place is uniform."""
    t = 1.7e9 + np.arange(4000) * 1e-3
    assert np.ptp(np.diff(t)) > 1e-6 * 1e-3  # (rounding alone moves the steps beyond UNIFORM_RTOL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        e = Experiment(t, {"x": np.sin(3 * (t - t[0]))}, {"f": np.cos(t - t[0])})
        part = e.slice(100, 3000, "part")
    assert np.array_equal(e.time, t) and part.n == 2900


def test_rows_missing_from_a_uniform_record_become_gaps_when_gaps_are_on():
    """A fourth outside check: a record with 100 rows lost (its time jumps by 101 steps)
    was refused with "split it where a sample is missing", which a spec cannot do (it takes
    one training record); with gaps = true the rows are NaN gaps on the full grid."""
    t = np.arange(3000) * 1e-3
    keep = np.r_[0:1200, 1300:3000]
    x, f = np.sin(3 * t), np.cos(7 * t)
    with pytest.raises(CvxidError, match=r"the time jumps by whole steps \(100 rows missing\): load it with gaps = "
                                         r"true and they become gaps"):
        Experiment(t[keep], {"x": x[keep]}, {"f": f[keep]})
    e = Experiment(t[keep], {"x": x[keep]}, {"f": f[keep]}, gaps=True)
    assert e.n == 3000 and np.allclose(e.time, t) and np.isnan(e.output("x")[1200:1300]).all()
    assert np.array_equal(e.output("x")[keep], x[keep]) and [s.n for s in e.segments()] == [1200, 1700]
    off = np.r_[t[:1200], t[1300:] + 3e-4]  # a jump of 100.3 steps: not whole, refused as before
    with pytest.raises(CvxidError, match=r"time is not uniformly sampled \(step .*% off; up to 1 %"):
        Experiment(off, {"x": x[keep]}, {"f": f[keep]}, gaps=True)
    slower = np.r_[np.arange(1000) * 1e-3, 1 + np.arange(600) * 2e-3]  # 1 kHz, then 500 Hz: a changed rate
    with pytest.raises(CvxidError, match=r"time is not uniformly sampled \(step 0.002"):  # (a review: read as
        Experiment(slower, {"x": np.sin(slower)}, {"f": np.cos(slower)}, gaps=True)  # 599 rows lost, 40 % dropped)


def test_a_records_facts_are_computed_once_while_it_lives_and_never_read_by_another():
    """The fits of one record share what no parameter changes (cvxid.data.remembered): a
    fact is computed once per record object and key; a record that is gone takes its facts
    with it, so a new one (whatever its place in memory) computes its own."""
    import gc

    from cvxid.data.remembered import _FACTS, remembered

    calls = []

    def fact(value):
        calls.append(value)
        return value

    record = Experiment(T, {"x": np.sin(T)}, {"f": np.cos(T)})
    assert remembered(record, "a", lambda: fact(1)) == 1 and remembered(record, "a", lambda: fact(2)) == 1
    assert remembered(record, "b", lambda: fact(3)) == 3 and calls == [1, 3]
    identity = id(record)
    del record
    gc.collect()
    assert identity not in _FACTS
    for _ in range(20):  # (new records, some perhaps where the old one was)
        other = Experiment(T, {"x": np.sin(T)}, {"f": np.cos(T)})
        assert remembered(other, "a", lambda: fact(4)) == 4
        del other
    assert calls == [1, 3] + [4] * 20
