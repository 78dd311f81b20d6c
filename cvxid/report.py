"""Reports of a run: ``result.json``, ``report.md`` and PNG figures in one folder."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.pyplot as plt

from .errors import CvxidError
from .diagnostics import compare
from .plots import path_figure


def write_report(result, out) -> Path:
    """Write ``result.json``, ``report.md``, ``path.png`` and ``test_fit.png`` into ``out``."""
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CvxidError(f"cannot create the output folder {out} ({exc.strerror})") from None
    data = result.to_dict()
    figures = {}
    fig = path_figure(result.path, result.model.lam)
    fig.savefig(out / "path.png", dpi=110)
    plt.close(fig)
    figures["path"] = "path.png"
    if result.diagnosis is not None:
        fig = result.diagnosis.plot()
        fig.savefig(out / "diagnosis.png", dpi=110)
        plt.close(fig)
        figures["diagnosis"] = "diagnosis.png"
    if result.refinement is not None and result.refinement.steps:
        fig = result.refinement.plot()
        fig.savefig(out / "refinement.png", dpi=110)
        plt.close(fig)
        figures["refinement"] = "refinement.png"
    if result.order_search is not None:
        fig = result.order_search.plot()
        fig.savefig(out / "orders.png", dpi=110)
        plt.close(fig)
        figures["orders"] = "orders.png"
    if result.test is not None:
        cmp = compare(result.model, result.test)
        data["test_fit_percent"] = cmp.fit_percent
        data["test_k_step_fit_percent"] = cmp.k_step_fit_percent
        if cmp.free_run is not None:
            fig = cmp.plot()
            fig.savefig(out / "test_fit.png", dpi=110)
            plt.close(fig)
            figures["test_fit"] = "test_fit.png"
        else:
            result.warnings.append(cmp.message)
            data["warnings"] = result.warnings
    data["figures"] = figures
    (out / "result.json").write_text(json.dumps(data, indent=2, allow_nan=True))
    md = [f"# {result.spec.name}", "", "```", result.summary(), "```", ""]
    md += [f"![{k}]({v})" for k, v in figures.items()]
    (out / "report.md").write_text("\n".join(md) + "\n")
    return out / "result.json"
