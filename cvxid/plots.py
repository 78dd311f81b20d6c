"""Figures (matplotlib, no screen needed): the lambda path and a model against data."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import LogFormatter, NullLocator  # noqa: E402

_SUPERSCRIPT = str.maketrans("-0123456789", "\u207b\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079")


class PlainLogFormatter(LogFormatter):
    """Log-axis tick labels in plain text, ``10⁻³`` and ``2×10⁻³``, where they are labelled at
    all (matplotlib's choice of ticks).  Its default labels are mathtext, whose first use
    in a process costs 0.3 s: a report of three log axes drew 10 % faster."""

    def __call__(self, x, pos=None):
        if not super().__call__(x, pos):
            return ""
        exponent = int(np.floor(np.log10(abs(x)) + 1e-9))
        coefficient = f"{abs(x) / 10.0**exponent:.3g}"  # (a view of about a decade may tick 1.5 and 3.5)
        power = f"10{str(exponent).translate(_SUPERSCRIPT)}"
        return ("\u2212" if x < 0 else "") + (power if coefficient == "1" else f"{coefficient}\u00d7{power}")


LOG_SPAN = 10.0
"""Data spanning less than this ratio keep a linear axis: a log axis over less than a
decade labels few ticks, all alike to three digits (a delay profile's simulation RMS from
0.01012 to 0.01015)."""


def log_scale(ax, axis: str = "y") -> None:
    """A logarithmic ``axis`` ("x" or "y") of ``ax`` for the data drawn on it so far,
    labelled by :class:`PlainLogFormatter`, where they are positive and span at least
    :data:`LOG_SPAN`; else the axis stays linear."""
    low, high = (ax.dataLim.x0, ax.dataLim.x1) if axis == "x" else (ax.dataLim.y0, ax.dataLim.y1)
    if not (np.isfinite(low) and np.isfinite(high) and low > 0 and high >= LOG_SPAN * low):
        return
    (ax.set_xscale if axis == "x" else ax.set_yscale)("log")
    which = ax.xaxis if axis == "x" else ax.yaxis
    which.set_major_formatter(PlainLogFormatter())
    which.set_minor_formatter(PlainLogFormatter(labelOnlyBase=False))


def path_figure(path, selected: float | None = None):
    """Coefficient traces (scaled) and validation error against log lambda."""
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    lam = path.lambdas
    scaled = np.array([f.scaled for f in path.fits])
    for j, name in enumerate(path.names):  # (past ten terms the colours repeat: the line style tells them apart)
        top.plot(lam, scaled[:, j], label=name, lw=1.2, ls=("-", "--", ":", "-.")[j // 10 % 4])
    log_scale(top, "x")
    if lam.max() >= 100 * lam.min():  # the decades are labelled; minor ticks on this shared axis cost 0.2 s
        top.xaxis.set_minor_locator(NullLocator())
    top.set_ylabel("scaled coefficient")
    top.legend(fontsize=7, ncol=3)
    top.set_title("lambda path")
    bottom.plot(lam, path.validation, "k.-", label="validation MSE")
    bottom.plot(lam, [f.train_mse for f in path.fits], "b.-", label="training MSE")
    log_scale(bottom)
    bottom.set_xlabel("lambda")
    bottom.legend()
    if selected is not None:
        for ax in (top, bottom):
            ax.axvline(selected, color="r", ls="--", lw=1)
    fig.tight_layout()
    return fig


def comparison_figure(time, measured, simulated, title: str = "free-run simulation against data",
                      from_record=None):
    """Measured and simulated output, with the error below; ``from_record`` (optional) is
    the same model's free run from the record's own start, drawn thin beside it."""
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True, height_ratios=[3, 1])
    top.plot(time, measured, "k", lw=0.8, label="measured")
    if from_record is not None:
        top.plot(time, from_record, color="tab:blue", lw=0.7, ls="--", label="model from the record's own start")
        bottom.plot(time, measured - from_record, color="tab:blue", lw=0.6, ls="--")
    top.plot(time, simulated, "r", lw=1.0, label="identified model")
    top.set_ylabel("output")
    top.legend()
    top.set_title(title, fontsize=10)
    bottom.plot(time, measured - simulated, "r", lw=0.8)  # (each model's error in its own colour)
    bottom.set_ylabel("measured \u2212 model")
    bottom.set_xlabel("time [s]")
    fig.tight_layout()
    return fig


def order_figure(table, best: int):
    """Test error against library order, with AIC/BIC beside it (the paper's Fig. 1)."""
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(table.index, table["test_mse"], "ko-", label="test MSE")
    log_scale(ax)
    ax.axvline(best, color="r", ls="--", lw=1, label=f"chosen order {best}")
    ax.set_xlabel("library order N = M")
    ax.set_ylabel("test MSE")
    ax.legend()
    fig.tight_layout()
    return fig


def coordinates_figure(time, measured: dict, simulated: dict, title: str = "free-run simulation of the test experiment"):
    """Measured and simulated signals, one panel per coordinate."""
    coords = list(simulated)
    fig, axes = plt.subplots(len(coords), 1, figsize=(8, 2.6 * len(coords)), sharex=True, squeeze=False)
    for ax, c in zip(axes[:, 0], coords):
        ax.plot(time, measured[c], "k", lw=0.8, label="measured")
        ax.plot(time, simulated[c], "r", lw=1.0, label="identified model")
        ax.set_ylabel(c)
    axes[0, 0].legend()
    axes[0, 0].set_title(title, fontsize=10)
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    return fig


def delay_profile_figure(taus, values, tau: float, interval=None, polished=None, final: float | None = None,
                         final_interval=None):
    """The delay profile of the equation error (the convex problem's optimal value against
    the delay), its estimate ``tau`` and 95 % ``interval``; ``polished`` (the output-error
    polish's :class:`~cvxid.identify.profile.DelayProfile`) adds a panel of the
    simulation error against the delay, with the final estimate and its interval
    (``final_interval``, the printed one: the profile's hulled with the standard error's;
    else the profile's own); without it, a ``final`` delay that the polish moved is marked
    on the first.  Each line and band names its method: the two estimates and intervals
    differ, and the run prints the last."""
    rows = 1 if polished is None else 2
    fig, axes = plt.subplots(rows, 1, figsize=(6, 4 if rows == 1 else 6.5), sharex=True, squeeze=False)
    top = axes[0, 0]
    top.plot(taus, values, "k.-")
    log_scale(top)
    top.axvline(tau, color="r", ls="--", lw=1, label=f"equation error: tau = {tau:.4g}")
    if interval is not None:
        top.axvspan(*interval, color="r", alpha=0.15, label="its 95 % interval")
    if polished is None and final is not None and not np.isclose(final, tau, rtol=1e-9, atol=0):
        top.axvline(final, color="b", ls="-", lw=1, label=f"output-error polish: tau = {final:.4g}")
    top.set_ylabel("equation-error MSE")
    top.legend(fontsize=8)
    if polished is not None:
        bottom = axes[1, 0]
        order = np.argsort(polished.taus)
        bottom.plot(np.asarray(polished.taus)[order], np.asarray(polished.values)[order], "b.-")
        log_scale(bottom)
        bottom.axvline(polished.estimate, color="b", ls="-", lw=1,
                       label=f"output-error polish (final): tau = {polished.estimate:.4g}")
        bottom.axvspan(*(polished.interval if final_interval is None else final_interval), color="b", alpha=0.15,
                       label="its 95 % interval (the printed one)")
        bottom.set_ylabel("simulation RMS")
        bottom.legend(fontsize=8)
    axes[-1, 0].set_xlabel("delay tau [s]")
    fig.tight_layout()
    return fig


def refinement_figure(labels, series: dict):
    """Errors before and after each added effect: ``labels`` (start, then each effect) and
    named error series of the same length."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for (name, values), style in zip(series.items(), ("ko-", "rs--", "b^:")):
        ax.plot(range(len(values)), values, style, label=name)
    log_scale(ax)
    ax.set_xticks(range(len(labels)))
    ax.set_xticklabels(labels, rotation=20, ha="right", rotation_mode="anchor")
    ax.set_ylabel("error")
    ax.legend()
    ax.set_title("adding the missing effects")
    fig.tight_layout()
    return fig


def responses_figure(labels, comparisons):
    """One row of panels per model (``labels``: start, then each added effect), one column
    per coordinate (``comparisons``: a list of coordinate -> comparison): the measured
    output and the model's free run over the same record, the fit in the panel's title, so
    that where each effect mattered shows in the response itself.  These are the
    diagnosis's own models and comparisons (before the run's output-error polish; a row
    whose label says ``(polished)`` is a model the diagnosis judged polished), and a last
    row ``final …`` may show the run's final model after it; the figure's title says so."""
    coords = list(comparisons[0])
    fig, axes = plt.subplots(len(comparisons), len(coords), figsize=(8 * len(coords) ** 0.5, 1.9 * len(comparisons)
                                                                      + 0.6), sharex=True, squeeze=False)
    for row, label, compared in zip(axes, labels, comparisons):
        for ax, coord in zip(row, coords):
            c = compared[coord]
            ax.plot(c.time, c.measured, "k", lw=0.8, label="measured (test record)")
            name = label if len(coords) == 1 else f"{label}, {coord}"
            if c.free_run is not None:
                ax.plot(c.time, c.free_run, "r", lw=1.0, label="free run of the model")
                ax.set_title(f"{name}: fit {c.fit_percent:.1f} % (the noise allows {c.ceiling_percent:.1f} %)",
                             fontsize=9)
            else:
                ax.set_title(f"{name}: {c.message}", fontsize=9)
            ax.set_ylabel("output" if len(coords) == 1 else coord)
    axes[0, 0].legend(fontsize=8, loc="lower left", ncol=2)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    polished = " (the last: the run's final model after it, from the estimated initial state)" \
        if labels[-1].startswith("final") else ""
    top = _suptitle(fig, "the diagnosis's models, each added effect in turn (free run from the record's first "
                         f"state, before the output-error polish){polished}", 9)
    fig.tight_layout(rect=(0, 0, 1, top))
    return fig


def _suptitle(fig, text: str, fontsize: float) -> float:
    """``fig``'s title, wrapped to the figure's width (a title wider than the figure was
    cut at both sides); returns the share of the height left below it."""
    import textwrap

    width, height = fig.get_size_inches()
    lines = textwrap.wrap(text, width=max(20, int(width * 72 / (0.55 * fontsize))))
    fig.suptitle("\n".join(lines), fontsize=fontsize)
    return 1.0 - len(lines) * 1.25 * fontsize / 72 / height


def signature_figure(eff, coordinate: str = "x", span: float = 2.0):
    """An effect's signature (a catalogue :class:`~cvxid.model.library.Effect`): its force
    against the state it depends on."""
    term = eff.build(coordinate)
    grid = np.linspace(-span, span, 401)
    on_velocity = any(s.endswith("'") for s in term.symbols)
    states = {coordinate: 0.0 * grid, coordinate + "'": 0.0 * grid}
    states[coordinate + "'" if on_velocity else coordinate] = grid
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot(grid, np.broadcast_to(term.evaluate(states), grid.shape), "k")
    ax.axhline(0, color="gray", lw=0.6)
    ax.axvline(0, color="gray", lw=0.6)
    ax.set_xlabel(coordinate + "'" if on_velocity else coordinate)
    ax.set_ylabel(term.name)
    ax.set_title(f"{eff.name}: {eff.meaning}", fontsize=9)
    fig.tight_layout()
    return fig


def residual_figure(res, bins: int = 21, title: str | None = None):
    """The equation error in time and binned against position and velocity (mean and spread
    per bin): of one equation (``res``), or a row of panels for each equation (``res``:
    equation -> its residuals)."""
    views = res if isinstance(res, dict) else {"": res}
    fig, axes = plt.subplots(len(views), 3, figsize=(12, 3.5 * len(views)), squeeze=False)
    top = _suptitle(fig, title, 10) if title else 1.0
    for row, (label, view) in zip(axes, views.items()):
        row[0].plot(view.time, view.residual, "k", lw=0.5)
        row[0].set_xlabel("time [s]")
        row[0].set_ylabel("equation error (force units)" if not label else f"{label}: equation error")
        for ax, against, symbol in ((row[1], "position", label or "x"), (row[2], "velocity", (label or "x") + "'")):
            b = view.binned(against, bins)
            ax.errorbar(b["center"], b["mean"], yerr=b["std"], fmt="ko-", ms=3)
            ax.axhline(0, color="gray", lw=0.6)
            ax.set_xlabel(symbol)
    fig.tight_layout(rect=(0, 0, 1, top))
    return fig


def partial_residual_figure(diagnosis, top: int = 3):
    """Added-variable plots: the model's residual against each top candidate's column,
    both orthogonalised against the model (a straight line means the effect is missing)."""
    names = list(diagnosis.ranking.index[:top])
    fig, axes = plt.subplots(1, len(names), figsize=(4 * len(names), 3.5), squeeze=False)
    r = diagnosis.residual
    step = max(1, r.size // 2000)
    for ax, name in zip(axes[0], names):
        g = diagnosis.columns[name]
        ax.plot(g[::step], r[::step], "k.", ms=2)
        slope = (g @ r) / (g @ g) if g @ g > 0 else 0.0  # (a column the model spans: nothing to draw)
        ax.plot(g[::step], slope * g[::step], "r", lw=1)
        ax.set_title(f"{name} (ERR {diagnosis.ranking.loc[name, 'err']:.2f})", fontsize=9)
        ax.set_xlabel(f"{diagnosis.ranking.loc[name, 'term']} (orthogonalised)")
    axes[0][0].set_ylabel("model residual (orthogonalised)")
    fig.tight_layout()
    return fig
