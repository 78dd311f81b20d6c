"""Figures (matplotlib, no screen needed): the lambda path and a model against data."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def path_figure(path, selected: float | None = None):
    """Coefficient traces (scaled) and validation error against log lambda."""
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    lam = path.lambdas
    scaled = np.array([f.scaled for f in path.fits])
    for j, name in enumerate(path.names):
        top.plot(lam, scaled[:, j], label=name, lw=1.2)
    top.set_xscale("log")
    top.set_ylabel("scaled coefficient")
    top.legend(fontsize=7, ncol=3)
    top.set_title("lambda path")
    bottom.plot(lam, path.validation, "k.-", label="validation MSE")
    bottom.plot(lam, [f.train_mse for f in path.fits], "b.-", label="training MSE")
    bottom.set_yscale("log")
    bottom.set_xlabel("lambda")
    bottom.legend()
    if selected is not None:
        for ax in (top, bottom):
            ax.axvline(selected, color="r", ls="--", lw=1)
    fig.tight_layout()
    return fig


def comparison_figure(time, measured, simulated, title: str = "free-run simulation against data"):
    """Measured and simulated output, with the error below."""
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True, height_ratios=[3, 1])
    top.plot(time, measured, "k", lw=0.8, label="measured")
    top.plot(time, simulated, "r", lw=1.0, label="identified model")
    top.set_ylabel("output")
    top.legend()
    top.set_title(title)
    bottom.plot(time, measured - simulated, "k", lw=0.8)
    bottom.set_ylabel("error")
    bottom.set_xlabel("time [s]")
    fig.tight_layout()
    return fig


def order_figure(table, best: int):
    """Test error against library order, with AIC/BIC beside it (the paper's Fig. 1)."""
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogy(table.index, table["test_mse"], "ko-", label="test MSE")
    ax.axvline(best, color="r", ls="--", lw=1, label=f"chosen order {best}")
    ax.set_xlabel("library order N = M")
    ax.set_ylabel("test MSE")
    ax.legend()
    fig.tight_layout()
    return fig


def refinement_figure(refinement):
    """Test error (and free-run fit) before and after each added effect."""
    steps = refinement.steps
    fig, ax = plt.subplots(figsize=(6, 4))
    labels = ["start"] + [s.added for s in steps]
    errors = [steps[0].test_mse_before] + [s.test_mse_after for s in steps] if steps else []
    ax.semilogy(range(len(errors)), errors, "ko-")
    ax.set_xticks(range(len(labels)))
    ax.set_xticklabels(labels, rotation=20)
    ax.set_ylabel("test equation-error MSE")
    ax.set_title("adding the missing effects")
    fig.tight_layout()
    return fig
