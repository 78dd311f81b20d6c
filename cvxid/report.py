"""Reports of a run: ``result.json``, ``report.md`` and PNG figures in one folder."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from .errors import CvxidError
from .plots import comparison_figure, path_figure
from .simulate import SimulationDiverged


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
    if result.order_search is not None:
        fig = result.order_search.plot()
        fig.savefig(out / "orders.png", dpi=110)
        plt.close(fig)
        figures["orders"] = "orders.png"
    if result.test is not None:
        test = result.test
        coord = result.spec.model.coordinate
        x = test.output(coord)
        try:
            v0 = float(np.polyfit(test.time[:50], x[:50], 2)[1])  # slope of a local quadratic at t0
            sim, _ = result.model.simulate(test, float(x[0]), v0)
            fit = 100 * (1 - np.linalg.norm(x - sim) / np.linalg.norm(x - x.mean()))
            data["test_fit_percent"] = float(fit)
            fig = comparison_figure(test.time, x, sim, f"test data: free-run fit {fit:.1f} %")
            fig.savefig(out / "test_fit.png", dpi=110)
            plt.close(fig)
            figures["test_fit"] = "test_fit.png"
        except SimulationDiverged as exc:
            data["test_fit_percent"] = None
            result.warnings.append(str(exc))
            data["warnings"] = result.warnings
    data["figures"] = figures
    (out / "result.json").write_text(json.dumps(data, indent=2, allow_nan=True))
    md = [f"# {result.spec.name}", "", "```", result.summary(), "```", ""]
    md += [f"![{k}]({v})" for k, v in figures.items()]
    (out / "report.md").write_text("\n".join(md) + "\n")
    return out / "result.json"
