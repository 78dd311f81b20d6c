"""Reports of a run: ``result.json``, ``report.md`` and PNG figures in one folder."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from cvxid.errors import CvxidError


def plain(value):
    """JSON-safe values: NaN and infinities become null (strict JSON has neither), numpy's
    numbers and truth values Python's."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def records(frame) -> dict:
    """A DataFrame as {row: {column: value}} with plain floats (JSON-ready)."""
    return {str(i): {str(k): float(v) for k, v in row.items()} for i, row in frame.iterrows()}


def coupled_fit_figure(compared: dict):
    """Every coordinate's free run on the test record (``compared``: coordinate ->
    :class:`~cvxid.diagnosis.compare.Comparison`) from its estimated start."""
    from cvxid.plots import coordinates_figure  # matplotlib is imported when a figure is drawn

    fits = ", ".join(f"{c} {m.fit_percent:.1f} % ({m.record_fit_percent:.1f} %; noise allows {m.ceiling_percent:.1f} %)"
                     for c, m in compared.items())
    first = next(iter(compared.values()))
    return coordinates_figure(first.time, {c: m.measured for c, m in compared.items()},
                              {c: m.free_run for c, m in compared.items()},
                              f"free-run fit {fits}\ninitial state estimated (in brackets: from the record's own start)")


def _final_label(result) -> str:
    """The final model's label in the refinement's figures: the effects the diagnosis by
    simulation error added, and those of the loop the polish set to 0."""
    from cvxid.diagnosis.refine import final_label, zeroed

    later = result.simulation_refinement
    added = [s.added for s in later.steps if s.kept] if later is not None else []
    removed = [s.added for s in zeroed(result.refinement.steps, result.system.coefficients)]
    return final_label(added, removed) if result.polish is not None else final_label()


def prepare_folder(out) -> Path:
    """The output folder, created if needed and checked writable (a clear error when it
    cannot be), before any file is written."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CvxidError(f"--out {out} is a file, not a folder; give a folder for result.json and the figures")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CvxidError(f"cannot create the output folder {out} ({exc.strerror}); choose another --out") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise CvxidError(f"cannot write into the output folder {out} (permission denied); choose another --out")
    earlier_run(out)  # a result.json cvxid did not write is refused now, not after the run
    (out / MARKER).touch()  # (a run stopped before its result.json leaves files the next run may replace)
    return out


MARKER = ".cvxid"
"""An empty file marking a folder cvxid writes its reports into."""


FIGURES = ("path", "delay_profile", "diagnosis", "refinement", "responses", "residuals", "orders", "test_fit")
"""The figures a report may hold (:func:`write_report`)."""
WRITTEN = ("report.md", "model.json", *(f"{name}.png" for name in FIGURES))
"""The files a report writes beside ``result.json``."""


def earlier_run(out: Path) -> dict | None:
    """What an earlier run left in ``out``: its ``result.json`` (its ``name`` and the
    ``figures`` it wrote), or None when the folder holds none.  A ``result.json`` that is
    not a cvxid result, or files of a report's names (:data:`WRITTEN`) without one in a
    folder cvxid has not written to (:data:`MARKER`: a run stopped before its
    ``result.json``), are an error: cvxid replaces only its own files."""
    path = out / "result.json"
    if not path.exists():
        theirs = sorted(name for name in WRITTEN if (out / name).exists())
        if theirs and not (out / MARKER).exists():
            raise CvxidError(f"--out {out} holds {', '.join(theirs)} but no result.json of an earlier cvxid run: "
                             "cvxid replaces only its own files; choose another --out, or move those files")
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        data = None
    if not (isinstance(data, dict) and isinstance(data.get("name"), str) and isinstance(data.get("figures"), dict)):
        raise CvxidError(f"--out {out} holds a result.json that cvxid did not write (or cannot read); cvxid "
                         "replaces only its own results: choose another --out, or move that file")
    return data


def write_atomically(path: Path, write) -> None:
    """``write(temporary_path)``, then move the file into place in one step: a run killed
    midway never leaves a half-written ``path`` (the old file stays whole until then)."""
    temporary = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        write(temporary)
        os.replace(temporary, path)
    except OSError as exc:
        raise CvxidError(f"cannot write {path} ({exc.strerror}); choose another --out") from None
    finally:
        temporary.unlink(missing_ok=True)


FAST_PNG = {"compress_level": 1}  # zlib's fastest: 0.1 s less for a report's seven figures, files 10 % larger


def write_report(result, out) -> tuple[Path, str | None]:
    """Write ``result.json``, ``report.md``, ``model.json`` (the identified system, for
    :meth:`~cvxid.identified.IdentifiedSystem.load`; one equation also reads with
    :meth:`~cvxid.identified.IdentifiedModel.load`) and the figures (``test_fit``, and when
    the run made them ``path`` (when it selected: a path of listed terms alone is flat),
    ``delay_profile``, ``diagnosis``, ``refinement``,
    ``orders``; when the diagnosis added an effect ``responses`` and ``residuals``) into ``out``, each file atomically, ``result.json`` last.  Returns its path
    and what an earlier run had left there (:func:`earlier_run`), or None."""
    import matplotlib.pyplot as plt  # imported when a report is written, not with cvxid

    from cvxid.plots import delay_profile_figure, path_figure

    out = prepare_folder(out)
    earlier = earlier_run(out)
    replaced = f"'{earlier['name']}'" if earlier else None
    data = result.to_dict()
    system = result.system
    added = result.refinement is not None and bool(result.refinement.steps)
    final = result.comparisons if result.polish is not None else None  # (else the diagnosis's last model is final)
    equation = result.unpolished or system  # (the equation error's model: its delay profile, estimate and interval)
    plotters = {
        "path": (lambda: path_figure(result.path, result.lam))
        if result.path is not None and (result.path.problem.penalties > 0).any() else None,  # (flat without)
        "delay_profile": (lambda: delay_profile_figure(
            *equation.profile, equation.tau, equation.info.get("tau_interval"),
            result.polish.profile if result.polish is not None else None, system.tau,
            (result.tau or {}).get("interval") if result.polish is not None else None))
        if equation.profile is not None else None,
        "diagnosis": result.diagnosis.plot if result.diagnosis is not None else None,
        "refinement": (lambda: result.refinement.plot(final, result.test_mse, _final_label(result))) if added else None,
        "responses": (lambda: result.refinement.plot_responses(final, _final_label(result))) if added else None,
        "residuals": (lambda: result.refinement.plot_residuals(result.test)) if added else None,
        "orders": result.order_search.plot if result.order_search is not None else None,
    }
    compared = result.comparisons or {}
    if compared and all(c.free_run is not None for c in compared.values()):
        plotters["test_fit"] = result.test_fit.plot if len(compared) == 1 else (lambda: coupled_fit_figure(compared))
    figures = {}
    for name, plot in plotters.items():
        if plot is not None:
            fig = plot()
            write_atomically(out / f"{name}.png", lambda p: fig.savefig(p, dpi=110, format="png", pil_kwargs=FAST_PNG))
            plt.close(fig)
            figures[name] = f"{name}.png"
    data["figures"] = figures
    for stale in set((earlier or {}).get("figures", {}).values()) - set(figures.values()):
        if "/" not in stale and stale.endswith(".png"):  # the earlier run's figures this run did not draw
            (out / stale).unlink(missing_ok=True)
    try:
        model = json.dumps(system.to_dict(), indent=2)  # reload with IdentifiedSystem.load (or IdentifiedModel.load)
        write_atomically(out / "model.json", lambda p: p.write_text(model))
        data["model_file"] = "model.json"
    except CvxidError as exc:  # user-defined Python terms cannot be written
        data["warnings"] = data["warnings"] + [f"model.json not written: {exc}"]
    text = json.dumps(plain(data), indent=2, allow_nan=False)
    md = [f"# {result.spec.name}", "", "```", result.summary(), "```", ""]
    md += [f"![{k}]({v})" for k, v in figures.items()]
    write_atomically(out / "report.md", lambda p: p.write_text("\n".join(md) + "\n"))
    write_atomically(out / "result.json", lambda p: p.write_text(text))  # last: its presence means a whole run
    return out / "result.json", replaced
