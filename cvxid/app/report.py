"""Reports of a run: ``result.json``, ``report.md`` and PNG figures in one folder."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from cvxid.diagnose.diagnosis import compare
from cvxid.errors import CvxidError
from cvxid.plots import path_figure


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


def prepare_folder(out) -> Path:
    """The output folder, created if needed (a clear error when it cannot be)."""
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CvxidError(f"cannot create the output folder {out} ({exc.strerror})") from None
    return out


def write_report(result, out) -> Path:
    """Write ``result.json``, ``report.md``, ``model.json`` (the identified model, for
    :meth:`IdentifiedModel.load`) and the figures (``path``, ``test_fit`` and, when the run
    made them, ``diagnosis``, ``refinement``, ``orders``) into ``out``."""
    if hasattr(result, "write"):  # a coupled run writes its own report
        return result.write(out)
    out = prepare_folder(out)
    data = result.to_dict()
    plotters = {
        "path": (lambda: path_figure(result.path, result.model.lam)) if result.path is not None else None,
        "diagnosis": result.diagnosis.plot if result.diagnosis is not None else None,
        "refinement": result.refinement.plot if result.refinement is not None and result.refinement.steps else None,
        "orders": result.order_search.plot if result.order_search is not None else None,
    }
    if result.test is not None:
        cmp = compare(result.model, result.test)
        data["test_fit_percent"] = cmp.fit_percent
        data["test_k_step_fit_percent"] = cmp.k_step_fit_percent
        if cmp.free_run is not None:
            plotters["test_fit"] = cmp.plot
        else:
            result.warnings.append(cmp.message)
            data["warnings"] = result.warnings
    figures = {}
    for name, plot in plotters.items():
        if plot is not None:
            fig = plot()
            fig.savefig(out / f"{name}.png", dpi=110)
            plt.close(fig)
            figures[name] = f"{name}.png"
    data["figures"] = figures
    try:
        result.model.save(out / "model.json")  # reload with IdentifiedModel.load
        data["model_file"] = "model.json"
    except CvxidError as exc:  # user-defined Python terms cannot be written
        result.warnings.append(str(exc))
    (out / "result.json").write_text(json.dumps(plain(data), indent=2, allow_nan=False))
    md = [f"# {result.spec.name}", "", "```", result.summary(), "```", ""]
    md += [f"![{k}]({v})" for k, v in figures.items()]
    (out / "report.md").write_text("\n".join(md) + "\n")
    return out / "result.json"
