"""The files of a run: written atomically, into a folder that is checked first, and a rerun
into another run's folder says so."""

import json
import os
import re

import pytest

from cvxid.app import report as report_module
from cvxid.app.cli import main
from cvxid.app.report import write_atomically
from cvxid.errors import CvxidError

from .test_pipeline import write_spec


def test_a_write_that_dies_midway_leaves_the_old_file_whole_and_no_partial_file(tmp_path):
    target = tmp_path / "result.json"
    target.write_text('{"name": "before"}')

    def dies(path):
        path.write_text('{"name": "aft')  # half of the new file ...
        raise KeyboardInterrupt  # ... then the run is killed

    with pytest.raises(KeyboardInterrupt):
        write_atomically(target, dies)
    assert json.loads(target.read_text()) == {"name": "before"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result.json"]
    write_atomically(target, lambda p: p.write_text('{"name": "after"}'))
    assert json.loads(target.read_text()) == {"name": "after"}


def test_a_write_the_system_refuses_is_a_clear_error(tmp_path):
    with pytest.raises(CvxidError, match=r"cannot write .*missing/result.json .*choose another --out"):
        write_atomically(tmp_path / "missing" / "result.json", lambda p: p.write_text("{}"))


def test_out_that_is_a_file_or_unwritable_fails_before_any_work(tmp_path, capsys, monkeypatch):
    import cvxid.app.run

    spec = write_spec(tmp_path)
    monkeypatch.setattr(cvxid.app.run, "run", lambda spec: pytest.fail("the run started"))
    afile = tmp_path / "taken"
    afile.write_text("mine")
    assert main(["run", str(spec), "--out", str(afile)]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err and afile.read_text() == "mine"
    locked = tmp_path / "locked"
    locked.mkdir()
    # (tests may run as root, whom permissions do not stop: the check itself is what is tested)
    monkeypatch.setattr(report_module.os, "access", lambda path, mode: os.fspath(path) != os.fspath(locked))
    assert main(["run", str(spec), "--out", str(locked)]) == 2
    assert "cannot write into the output folder" in capsys.readouterr().err and not any(locked.iterdir())


def test_a_rerun_into_another_runs_folder_says_so(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(write_spec(tmp_path)), "--out", str(out)]) == 0
    assert "replacing" not in capsys.readouterr().out
    other = tmp_path / "other"
    other.mkdir()
    assert main(["run", str(write_spec(other)), "--out", str(out)]) == 0
    assert "replacing the files of an earlier run of 'small'" in capsys.readouterr().out
    assert not [p for p in out.iterdir() if p.name.endswith(".partial")]


def test_a_rerun_removes_the_earlier_runs_figures_and_a_foreign_result_is_refused(tmp_path, capsys):
    """The earlier run's figures that this run does not draw go (they described another
    model); a result.json cvxid did not write is refused before any work, untouched."""
    import json

    out = tmp_path / "out"
    out.mkdir()
    (out / "diagnosis.png").write_bytes(b"an earlier run's figure")
    (out / "notes.png").write_bytes(b"the user's own")
    (out / "result.json").write_text(json.dumps({"name": "earlier", "figures": {"diagnosis": "diagnosis.png"}}))
    assert main(["run", str(write_spec(tmp_path)), "--out", str(out)]) == 0
    assert "replacing the files of an earlier run of 'earlier'" in capsys.readouterr().out
    assert not (out / "diagnosis.png").exists() and (out / "notes.png").exists() and (out / "test_fit.png").exists()

    def refused(folder: str, name: str, text: str, said: str):
        """--out into a folder holding the user's ``name``: refused, saying ``said``, untouched."""
        theirs = tmp_path / folder
        theirs.mkdir()
        (theirs / name).write_text(text)
        assert main(["run", str(write_spec(tmp_path)), "--out", str(theirs)]) == 2
        assert said in capsys.readouterr().err
        assert (theirs / name).read_text() == text and len(list(theirs.iterdir())) == 1

    refused("foreign", "result.json", '{"accuracy": 0.93}', "holds a result.json that cvxid did not write")
    # a report's own names without a result.json beside them are the user's (an outside check lost its notes)
    refused("notes", "report.md", "my notes", "holds report.md but no result.json of an earlier cvxid run")
    # a run stopped before its result.json (its figures written, then Ctrl-C) leaves a folder the next run reuses
    stopped = tmp_path / "stopped"
    assert main(["run", str(write_spec(tmp_path)), "--out", str(stopped)]) == 0
    (stopped / "result.json").unlink()
    assert main(["run", str(write_spec(tmp_path)), "--out", str(stopped)]) == 0 and (stopped / "result.json").exists()


def test_run_profile_says_where_the_seconds_went(tmp_path, capsys):
    """`cvxid run SPEC --profile`: a table of stages whose seconds lie within the run's; a
    stage the spec does not ask for (the polish) takes none."""
    from cvxid.app.cli import main

    from .test_sensor import SIMULATED, spec_text

    # its own noise seed: records another test simulated are remembered, and load in no time
    (tmp_path / "spec.toml").write_text(spec_text(SIMULATED.replace("seed = 1", "seed = 17")))
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--profile"]) == 0
    out = capsys.readouterr().out.split("where the seconds went")[1]
    assert "under Python's profiler, which slows the Python-heavy stages" in out.splitlines()[0]
    rows = {name: float(seconds) for name, seconds, *_ in (re.split(r"\s{2,}", line.strip())
                                                          for line in out.splitlines()[3:] if line.strip())}
    whole = rows.pop("the whole run")
    rows.pop("starting Python, importing cvxid")  # (NaN where /proc is missing)
    assert rows["data (load or simulate the records)"] > 0 and rows["delay profile (convex)"] > 0
    assert rows["output-error polish (simulations)"] == 0 and rows["bootstrap"] == 0
    assert all(0 <= seconds <= whole for seconds in rows.values()), rows


def test_the_path_figure_is_drawn_only_when_terms_were_selected(tmp_path):
    """hidden_friction lists its terms (L1 weight 0): its lambda path is flat and is not
    drawn; the same spec with an order-3 library to select from draws it."""
    import tomllib

    from cvxid.app.report import write_report
    from cvxid.app.run import run
    from cvxid.spec.load import parse_problem

    from .conftest import ROOT

    raw = tomllib.loads((ROOT / "problems" / "hidden_friction.toml").read_text())
    raw.pop("diagnose")
    raw["fit"] = {"estimator": "lasso"}
    write_report(run(parse_problem(raw, ROOT / "problems")), tmp_path / "listed")
    raw["model"]["library"] = {"order": 2, "cross": True}
    write_report(run(parse_problem(raw, ROOT / "problems")), tmp_path / "selected")
    assert not (tmp_path / "listed" / "path.png").exists() and (tmp_path / "listed" / "test_fit.png").is_file()
    assert (tmp_path / "selected" / "path.png").is_file()


def test_log_axes_are_labelled_in_plain_text_and_narrow_data_keep_a_linear_axis():
    """A log axis reads 10⁻⁴, never a mathtext
    string, whose first parse in a process costs 0.3 s; data spanning less than a decade
    keep a linear axis, whose labels differ (an eleventh outside check: a log axis over
    0.01012 … 0.01015 read 10⁻² at every tick)."""
    import numpy as np

    from cvxid.plots import delay_profile_figure

    wide = delay_profile_figure(np.linspace(0, 0.3, 7), np.logspace(-5, -2, 7), 0.1)
    narrow = delay_profile_figure(np.linspace(0, 0.3, 7), np.linspace(0.01012, 0.01015, 7), 0.1)
    labels = []
    for fig in (wide, narrow):
        fig.canvas.draw()
        axis = fig.axes[0].yaxis
        labels.append([t.get_text() for t in axis.get_majorticklabels() + axis.get_minorticklabels()
                       if t.get_text() and fig.axes[0].get_ylim()[0] <= t.get_position()[1] <= fig.axes[0].get_ylim()[1]])
    assert {"10\u207b\u2074", "10\u207b\u00b3"} <= set(labels[0]), labels[0]
    assert not any("$" in text for text in labels[0] + labels[1])
    assert narrow.axes[0].get_yscale() == "linear" and len(set(labels[1])) == len(labels[1]) >= 3, labels[1]


def test_the_delay_profile_figure_names_each_method_and_shades_the_printed_interval():
    """An eleventh outside check: the figure shaded the equation error's interval (0.117 …
    0.361) beside the output-error delay 0.2505, whose printed interval was 0.148 … 0.325,
    and named neither.  Now the equation error's profile, estimate and interval are named
    as such, and the polish's simulation-error profile has its own panel with the final
    delay and the printed interval."""
    import numpy as np
    from matplotlib.patches import Rectangle

    from cvxid.identify.profile import DelayProfile
    from cvxid.plots import delay_profile_figure

    taus = np.linspace(0, 0.5, 21)
    polished = DelayProfile(taus, 0.01 + (taus - 0.25) ** 2, 0.2505, (0.148, 0.309), 100.0)
    fig = delay_profile_figure(taus, 1e-8 * (1 + (taus - 0.275) ** 2), 0.275, (0.117, 0.361), polished, 0.2505,
                               (0.148, 0.325))
    top, bottom = fig.axes
    legends = [[t.get_text() for t in ax.get_legend().get_texts()] for ax in (top, bottom)]
    assert legends[0][0] == "equation error: tau = 0.275" and "output-error polish (final): tau = 0.2505" in legends[1]
    band = bottom.patches[0]  # (axvspan's; in data x, axes y)
    xs = [band.get_x(), band.get_x() + band.get_width()] if isinstance(band, Rectangle) else band.get_xy()[:, 0]
    assert np.isclose(min(xs), 0.148) and np.isclose(max(xs), 0.325), xs


def test_the_final_models_label_names_what_the_stages_after_the_loop_changed():
    """An eleventh outside check: the loop added cubic damping, the polish set it to 0 and
    the diagnosis by simulation error added x'|x'|; the figures' last point read 'final
    (polished)' after '+ cubic_damping'.  Its label now says both changes; a final model
    that kept the loop's effects reads as before."""
    from types import SimpleNamespace as Of

    from cvxid.app.report import _final_label
    from cvxid.diagnosis.refine import FINAL

    loop = Of(steps=[Of(added="cubic_damping", columns=["x'^3"]), Of(added="cubic_stiffness", columns=["x^3"])])
    later = Of(steps=[Of(added="quadratic_damping", kept=True), Of(added="offset", kept=False)])
    swapped = Of(refinement=loop, simulation_refinement=later, polish=object(),
                 system=Of(coefficients={"x'^3": 0.0, "x^3": 2.03, "x'|x'|": 0.4996}))
    assert _final_label(swapped) == f"{FINAL}:\n+ quadratic_damping, \u2212 cubic_damping"
    kept = Of(refinement=loop, simulation_refinement=None, polish=object(),
              system=Of(coefficients={"x'^3": 0.1, "x^3": 2.03}))
    assert _final_label(kept) == FINAL
    delay = Of(refinement=Of(steps=[Of(added="delay", columns=())]), simulation_refinement=None, polish=object(),
               system=Of(coefficients={}))
    assert _final_label(delay) == FINAL  # (a delay estimated again adds no column, and is not removed)
