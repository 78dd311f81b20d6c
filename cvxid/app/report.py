"""Reports of a run: ``result.json``, ``report.md`` and PNG figures in one folder."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from cvxid.errors import CvxidError
from cvxid.plots import coordinates_figure, delay_profile_figure, path_figure


def plain(value):
    """JSON-safe values: NaN and infinities become null (strict JSON has neither)."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def records(frame) -> dict:
    """A DataFrame as {row: {column: value}} with plain floats (JSON-ready)."""
    return {str(i): {str(k): float(v) for k, v in row.items()} for i, row in frame.iterrows()}


def coupled_fit_figure(test, system, table):
    """Every coordinate's free run on the test record from the estimated start in ``table``
    (:meth:`~cvxid.identified.IdentifiedSystem.compare`)."""
    start = {c: (table.loc[c, "initial_position"], table.loc[c, "initial_velocity"]) for c in table.index}
    fits = ", ".join(f"{c} {table.loc[c, 'fit_percent']:.1f} % ({table.loc[c, 'record_fit_percent']:.1f} %; "
                     f"noise allows {table.loc[c, 'noise_ceiling_percent']:.1f} %)" for c in table.index)
    return coordinates_figure(test.time, {c: test.output(c) for c in system.coordinates},
                              system.simulate(test, start),
                              f"free-run fit {fits}\ninitial state estimated (in brackets: from the record's own start)")


def prepare_folder(out) -> Path:
    """The output folder, created if needed (a clear error when it cannot be)."""
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CvxidError(f"cannot create the output folder {out} ({exc.strerror})") from None
    return out


def write_report(result, out) -> Path:
    """Write ``result.json``, ``report.md``, ``model.json`` (the identified system, for
    :meth:`~cvxid.identified.IdentifiedSystem.load`; one equation also reads with
    :meth:`~cvxid.identified.IdentifiedModel.load`) and the figures (``test_fit``, and when
    the run made them ``path``, ``delay_profile``, ``diagnosis``, ``refinement``,
    ``orders``) into ``out``."""
    out = prepare_folder(out)
    data = result.to_dict()
    system = result.system
    plotters = {
        "path": (lambda: path_figure(result.path, result.lam)) if result.path is not None else None,
        "delay_profile": (lambda: delay_profile_figure(*system.profile, system.tau, system.info.get("tau_interval")))
        if system.profile is not None else None,
        "diagnosis": result.diagnosis.plot if result.diagnosis is not None else None,
        "refinement": result.refinement.plot if result.refinement is not None and result.refinement.steps else None,
        "orders": result.order_search.plot if result.order_search is not None else None,
    }
    if result.test is not None and result.coupled and np.isfinite(result.test_fit["fit_percent"]).all():
        plotters["test_fit"] = lambda: coupled_fit_figure(result.test, system, result.test_fit)
    elif result.test is not None and not result.coupled and result.test_fit.free_run is not None:
        plotters["test_fit"] = result.test_fit.plot
    figures = {}
    for name, plot in plotters.items():
        if plot is not None:
            fig = plot()
            fig.savefig(out / f"{name}.png", dpi=110)
            plt.close(fig)
            figures[name] = f"{name}.png"
    data["figures"] = figures
    try:
        system.save(out / "model.json")  # reload with IdentifiedSystem.load (or IdentifiedModel.load)
        data["model_file"] = "model.json"
    except CvxidError as exc:  # user-defined Python terms cannot be written
        data["warnings"] = data["warnings"] + [f"model.json not written: {exc}"]
    (out / "result.json").write_text(json.dumps(plain(data), indent=2, allow_nan=False))
    md = [f"# {result.spec.name}", "", "```", result.summary(), "```", ""]
    md += [f"![{k}]({v})" for k, v in figures.items()]
    (out / "report.md").write_text("\n".join(md) + "\n")
    return out / "result.json"
