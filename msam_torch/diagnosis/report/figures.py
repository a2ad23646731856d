"""The gap report's figures: every one titled, its axes labelled with units (:class:`~.units.Units`)
and a legend below its axes (off the data), laid out by matplotlib's constrained layout with long
labels wrapped to their axes, rendered once to PNG at :data:`DPI` (the Markdown's files, the HTML's
embedded images, TensorBoard's images).

Per equation: the residual of the structure fitted where it holds over time and against each
signal (where; the record's edges, where the derivative estimate is unreliable, shaded and left
out of the axis scaling, :mod:`.edges`); the residual's autocorrelation and its cross-correlation with each input, with
the white-noise band +-1.96/sqrt(N) (:func:`correlations`). Per record: the free runs of the
starting, theta-refitted and adapted models against the measurement, and where the model has
inputs, the empirical frequency response (Welch cross-spectral estimate) of the data and of each
model's free run (:func:`frequency_response`).

Drawn fast: :class:`matplotlib.figure.Figure` on the Agg canvas (no pyplot); a line with more
samples than its figure has pixel columns is cut to the first, lowest, highest and last sample of
each column (:func:`columns`: the same pixels); log axes labelled in plain numbers, not mathtext.
The correlations and spectra are computed with NumPy's FFT, as statsmodels' ``acf``/``ccf`` and
scipy's ``welch``/``csd`` define them.
"""
from __future__ import annotations

import io
import math
import textwrap
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from msam_torch.diagnosis.report.edges import Edges, edges
from msam_torch.diagnosis.report.units import Units
from msam_torch.model.spec import split_derivative

DPI = 130
LAGS = 40  # correlation lags shown, at most (and at most a quarter of the residual)
BAND = 1.96  # white-noise band of a correlation: +-BAND / sqrt(N) (95 %)
LABEL_FILL = 1.3  # an axis label wraps beyond this many characters per point of its axes per point of font size
LEGEND_FILL = 14  # characters of a legend entry per inch of the figure's width (wrapped beyond)
EXCITED = 1e-3  # a frequency is shown where the input's power is at least this share of its peak
MODELS = ("start", "retuned", "adapted")
NAMES = {"measured": "measured", "start": "starting model", "retuned": "theta re-fitted", "adapted": "adapted model"}
COLOURS = {"measured": "black", "start": "tab:red", "retuned": "tab:orange", "adapted": "tab:green"}


@dataclass(frozen=True)
class Figure:
    """One rendered figure: ``name`` (file name), ``title`` and the PNG bytes."""

    name: str
    title: str
    png: bytes


def correlations(residual: np.ndarray, inputs: dict, lags: int = LAGS) -> dict:
    """Autocorrelation of ``residual`` at lags 0..L and its cross-correlation with each input at
    lags -L..L (``ccf[u][L + k]``: residual at t + k against the input at t), L at most a quarter
    of the samples; ``band``: the 95 % white-noise band 1.96/sqrt(N)."""
    r = np.asarray(residual, dtype=float)
    n = r.size
    lags = max(1, min(lags, n // 4))
    out = {"lags": lags, "n": n, "band": BAND / math.sqrt(n), "acf": np.zeros(lags + 1), "ccf": {}}
    if not r.std() > 0:  # a residual that is exactly constant correlates with nothing
        return out
    covariance = _lagged(r, r, lags)
    out["acf"] = covariance / covariance[0]
    for name, u in inputs.items():
        u = np.asarray(u, dtype=float)
        if not u.std() > 0:
            continue
        scale = r.std() * u.std()
        ahead, behind = _lagged(r, u, lags) / scale, _lagged(u, r, lags) / scale
        out["ccf"][name] = np.concatenate([behind[1:][::-1], ahead])
    return out


def _lagged(x: np.ndarray, y: np.ndarray, lags: int) -> np.ndarray:
    """``sum_t x[t + k] y[t] / N`` of the demeaned ``x`` and ``y`` at lags k = 0..``lags`` (the
    unadjusted cross-covariance of statsmodels' ``ccovf``), by FFT."""
    size = 2 * x.size
    spectrum = np.fft.rfft(x - x.mean(), size) * np.conj(np.fft.rfft(y - y.mean(), size))
    return np.fft.irfft(spectrum, size)[:lags + 1] / x.size


def frequency_response(t: np.ndarray, u: np.ndarray, ys: np.ndarray) -> tuple:
    """Empirical transfer estimate ``P_uy / P_uu`` (Welch, Hann windows of half the record)
    from ``u`` to each row of ``ys`` (B, N) at the frequencies the input excites (one-sided power
    at least :data:`EXCITED` of its peak); frequencies in cycles per time unit. The segments overlap
    by half and are each demeaned, as in ``scipy.signal.welch`` and ``csd``."""
    length = min(u.size, max(16, u.size // 2))
    taper = np.hanning(length + 1)[:-1]  # periodic Hann
    spectrum = lambda x: np.fft.rfft(taper * _demeaned(sliding_window_view(x, length, axis=-1)[..., ::length - length // 2, :]))
    du, dy = spectrum(u - u.mean()), spectrum(ys - ys.mean(-1, keepdims=True))
    puu, puy = (np.abs(du) ** 2).mean(-2), (np.conj(du) * dy).mean(-2)
    sides = np.full(puu.size, 2.0)
    sides[0] = 1.0
    if length % 2 == 0:
        sides[-1] = 1.0  # the Nyquist frequency has no mirror image
    f = np.fft.rfftfreq(length, float(np.median(np.diff(t))))
    keep = (sides * puu >= EXCITED * (sides * puu).max()) & (f > 0)
    return f[keep], puy[..., keep] / puu[keep]


def _demeaned(x: np.ndarray) -> np.ndarray:
    return x - x.mean(-1, keepdims=True)


def render(report, units: Units) -> list[Figure]:
    """Every figure of ``report`` (a :class:`~msam_torch.diagnosis.report.gap_report.GapReport`), in report order,
    as PNG."""
    return [_png(*drawn) for drawn in draw(report, units)]


def draw(report, units: Units) -> list[tuple]:
    """``(name, title, matplotlib figure)`` of every figure of ``report``, laid out, in report order."""
    figures = []
    for target, series in report.series.items():
        gap = next((g for g in report.equations if g.target == target), None)
        if series.get("where") is not None:
            t = np.asarray(series["where"]["t"].cpu())
            figures += _where(target, series["where"], units, edges(gap.estimator if gap else {}, target, t, units.times))
        residual = residuals(target, series, gap.estimator if gap else {})
        if residual is not None:
            figures.append(_correlation_figure(target, *residual, units))
    seen = set()
    for series in report.series.values():
        for label in ("train", "held_out"):
            run = series.get(f"free_run_{label}")
            if run is None or label in seen:
                continue
            seen.add(label)
            figures.append(_free_run(label, run, units))
            inputs = {u: np.asarray(v.cpu()) for u, v in run.get("inputs", {}).items()}
            inputs = {u: v for u, v in inputs.items() if np.isfinite(v).all() and v.std() > 0}
            if inputs:
                figures.append(_frequency(label, run, inputs, units))
    return figures


def _where(target: str, where: dict, units: Units, edge: Edges | None) -> list[tuple]:
    t, r, flagged = (np.asarray(where[k].cpu()) for k in ("t", "residual", "flagged"))
    model = where.get("model", "starting")
    inside = np.ones_like(flagged) if edge is None else edge.inside(t)
    fig, axes = _canvas((8, 3.4))
    ax = axes[0, 0]
    ax.plot(*columns(t, r, fig), lw=0.8, color="tab:blue", label=f"residual of the {model} structure fitted where it holds")
    if flagged.any():
        ax.scatter(t[flagged], r[flagged], s=6, color="tab:red", label="flagged (where it fails)")
    _shade_edges(ax, t, r, inside, edge)
    ax.set_xlabel(units.time), ax.set_ylabel(f"residual of {units.label(target)}")
    title = f"{target}: where the {model} model misses, over time"
    out = [_figure(fig, ax, f"{target}_residual_time", title)]
    values = where["values"]
    if values:
        fig, axes = _canvas((4 * len(values), 3.6), 1, len(values), sharey=True)
        for ax, (name, v) in zip(axes[0], values.items()):
            v = np.asarray(v.cpu())
            for rows, colour, label in ((~flagged & inside, "tab:blue", "model holds"),
                                        (flagged & inside, "tab:red", "flagged"),
                                        (~inside, "0.65", "record edges (derivative estimate unreliable)")):
                if rows.any():
                    ax.scatter(v[rows], r[rows], s=4, color=colour, label=label)
            ax.set_xlabel(units.label(name))
        _scale(axes[0, 0], r[inside])
        axes[0, 0].set_ylabel(f"residual of {units.label(target)}")
        title = f"{target}: residual of the {model} structure against each signal"
        out.append(_figure(fig, axes[0, 0], f"{target}_residual_vs_state", title))
    return out


def _shade_edges(ax, t: np.ndarray, r: np.ndarray, inside: np.ndarray, edge: Edges | None) -> None:
    """Shade the record's edges and scale the residual's axis to the samples between them."""
    if edge is None or not inside.any() or inside.all():
        return
    peak = lambda rows: np.abs(r[rows & np.isfinite(r)]).max(initial=0.0)
    clipped = "; clipped" if peak(~inside) > peak(inside) else ""
    for low, high in ((t[0], t[0] + edge.width), (t[-1] - edge.width, t[-1])):
        ax.axvspan(low, high, color="0.85", zorder=0,
                   label=f"record edges: derivative estimate unreliable ({edge.why}{clipped})" if low == t[0] else None)
    _scale(ax, r[inside])


def _scale(ax, values: np.ndarray) -> None:
    """Scale the y-axis to the finite ``values`` (if any) with a margin of 5 %."""
    values = values[np.isfinite(values)]
    if not values.size:
        return
    low, high = float(values.min()), float(values.max())
    pad = 0.05 * (high - low) or 1.0
    ax.set_ylim(low - pad, high + pad)


def residuals(target: str, series: dict, estimator: dict):
    """``(source, residuals per model, inputs, spacing)`` for the whiteness checks on the held-out
    (else training) record: the free-run error of the equation's state when it is measured (a
    measured signal, not an estimated derivative), else the one-step residual of the equation.
    Every ``stride``-th sample is kept (``spacing``: the time between them): the weak form's
    decimation, for a one-step residual at least the window of the target's derivative estimate
    (``estimator``: the equation's), which correlates neighbouring rows."""
    base, _ = split_derivative(target)
    stride = max(1, int(estimator.get("decimation", 1) or 1))
    for label in ("held_out", "train"):
        run = series.get(f"free_run_{label}")
        if run is None or base not in run["measured"]:
            continue
        y, yhat = np.asarray(run["measured"][base].cpu()), np.asarray(run["simulated"][base].cpu())
        found = {m: (y - yhat[k])[::stride] for k, m in enumerate(MODELS) if m != "start" and np.isfinite(yhat[k]).all()}
        inputs = {u: np.asarray(v.cpu())[::stride] for u, v in run.get("inputs", {}).items()}
        source = f"free-run error of {base} ({label.replace('_', '-')} record)"
        return (source, found, inputs, _spacing(run["t"], stride)) if found else None
    for label in ("held_out", "train"):
        step = series.get(f"one_step_{label}")
        if step is not None:
            stride = max(stride, int(estimator.get("derivatives", {}).get(base, {}).get("window", 1) or 1))
            y, yhat = np.asarray(step["y"].cpu()), np.asarray(step["yhat"].cpu())
            found = {m: (y - yhat[k])[::stride] for k, m in enumerate(MODELS) if m != "start"}
            inputs = {u: np.asarray(v.cpu())[::stride] for u, v in step.get("inputs", {}).items()}
            source = f"one-step residual of {target} ({label.replace('_', '-')} record)"
            return source, found, inputs, _spacing(step["t"], stride)
    return None


def _spacing(t, stride: int) -> float:
    return stride * float((t[-1] - t[0]) / max(t.shape[0] - 1, 1))


def _correlation_figure(target: str, source: str, residuals: dict, inputs: dict, spacing: float,
                        units: Units) -> tuple:
    found = {m: correlations(r, inputs) for m, r in residuals.items()}
    names = sorted({u for c in found.values() for u in c["ccf"]})
    fig, axes = _canvas((4.2 * (1 + len(names)), 3.6), 1, 1 + len(names))
    first = next(iter(found.values()))
    for m, c in found.items():
        axes[0, 0].plot(spacing * np.arange(c["lags"] + 1), c["acf"], marker=".", lw=0.8, color=COLOURS[m], label=NAMES[m])
        for ax, u in zip(axes[0, 1:], names):
            ax.plot(spacing * np.arange(-c["lags"], c["lags"] + 1), c["ccf"][u], marker=".", lw=0.8, color=COLOURS[m], label=NAMES[m])
    for ax in axes[0]:
        ax.axhspan(-first["band"], first["band"], color="grey", alpha=0.25, label=f"±1.96/√N (N = {first['n']})")
        ax.axhline(0, color="black", lw=0.5)
        ax.set_xlabel(f"lag ({units.times}; a sample every {spacing:.3g})")
    axes[0, 0].set_ylabel("autocorrelation (dimensionless)"), axes[0, 0].set_title("residual autocorrelation", fontsize=9)
    for ax, u in zip(axes[0, 1:], names):
        ax.set_ylabel(f"correlation with {u} (dimensionless)")
        ax.set_title(f"residual(t + lag) against {units.label(u)}", fontsize=9)
    return _figure(fig, axes[0, 0], f"{target}_residual_correlation", f"{target}: whiteness of the {source}")


def _free_run(label: str, run: dict, units: Units) -> tuple:
    states = list(run["measured"])
    t = np.asarray(run["t"].cpu())
    fig, axes = _canvas((8, 1.2 + 2.4 * len(states)), len(states), 1, sharex=True)
    for ax, x in zip(axes[:, 0], states):
        ax.plot(*columns(t, np.asarray(run["measured"][x].cpu()), fig), color=COLOURS["measured"], lw=1.2,
                label=NAMES["measured"])
        for k, m in enumerate(MODELS):
            ax.plot(*columns(t, np.asarray(run["simulated"][x][k].cpu()), fig), lw=0.9, color=COLOURS[m], label=NAMES[m])
        ax.set_ylabel(units.label(x))
    axes[-1, 0].set_xlabel(units.time)
    record = label.replace("_", "-")
    return _figure(fig, axes[0, 0], f"free_run_{label}", f"Free runs on the {record} record: measured and simulated")


def _frequency(label: str, run: dict, inputs: dict, units: Units) -> tuple:
    from matplotlib.ticker import FormatStrFormatter, LogFormatter, LogLocator, NullFormatter

    class Plain(LogFormatter):
        """The ticks a log axis labels, as plain numbers (``0.2``): no mathtext, whose first use costs
        a tenth of a second."""

        def __call__(self, x, pos=None):
            return f"{x:g}" if super().__call__(x, pos) else ""

    t = np.asarray(run["t"].cpu())
    pairs = [(x, u) for x in run["measured"] for u in inputs]
    fig, axes = _canvas((max(8.0, 4.6 * len(pairs)), 5.6), 2, len(pairs), sharex="col")
    for col, (x, u) in enumerate(pairs):
        simulated = np.asarray(run["simulated"][x].cpu())
        rows = np.vstack([np.asarray(run["measured"][x].cpu())[None], simulated])
        finite = np.isfinite(rows).all(-1)
        f, h = frequency_response(t, inputs[u], np.where(finite[:, None], rows, 0.0))
        for k, m in enumerate(("measured",) + MODELS):
            if finite[k]:
                style = {"lw": 1.6 if m == "measured" else 0.9, "color": COLOURS[m], "label": NAMES[m], "marker": ".",
                         "ms": 4}
                axes[0, col].loglog(f, np.abs(h[k]), **style)
                axes[1, col].semilogx(f, np.degrees(np.unwrap(np.angle(h[k]))), **style)
        axes[0, col].set_ylabel(units.ratio(x, u)), axes[0, col].set_title(f"{u} → {x}", fontsize=9)
        axes[1, col].set_ylabel("phase (degrees)"), axes[1, col].set_xlabel(units.frequency())
        axes[1, col].xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axes[1, col].xaxis.set_major_formatter(FormatStrFormatter("%g"))
        axes[1, col].xaxis.set_minor_formatter(NullFormatter())
        axes[0, col].yaxis.set_major_formatter(Plain(labelOnlyBase=False))
        axes[0, col].yaxis.set_minor_formatter(Plain(labelOnlyBase=False))
    title = f"Frequency response on the {label.replace('_', '-')} record: data and free runs (Welch estimate)"
    return _figure(fig, axes[0, 0], f"frequency_response_{label}", title)


def _figure(fig, legend_axis, name: str, title: str) -> tuple:
    """A matplotlib figure titled, its axis labels wrapped to their axes, the legend of
    ``legend_axis`` below the axes (off the data), laid out by the constrained layout."""
    fig.suptitle(textwrap.fill(title, int(11 * fig.get_figwidth())), fontsize=10)
    for ax in fig.axes:
        box = ax.get_position()
        for label, inches in ((ax.xaxis.label, box.width * fig.get_figwidth()),
                              (ax.yaxis.label, box.height * fig.get_figheight())):
            label.set_text(textwrap.fill(label.get_text(), max(16, int(LABEL_FILL * 72 * inches / label.get_fontsize()))))
    handles, labels = legend_axis.get_legend_handles_labels()
    columns = min(len(labels), 2)
    labels = [textwrap.fill(label, int(LEGEND_FILL * fig.get_figwidth() / columns)) for label in labels]
    fig.legend(handles, labels, loc="outside lower center", ncols=columns, fontsize=7, frameon=False)
    return name, title, fig


def _canvas(size: tuple, rows: int = 1, cols: int = 1, **shared) -> tuple:
    """A figure of ``size`` inches on the Agg canvas (no pyplot: nothing is registered or shown)
    with a ``rows`` x ``cols`` grid of axes, laid out by the constrained layout."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure as Drawing

    fig = Drawing(figsize=size, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, cols, squeeze=False, **shared)


def columns(x: np.ndarray, y: np.ndarray, fig) -> tuple[np.ndarray, np.ndarray]:
    """The samples of a line ``y(x)`` (``x`` increasing) that draw the same pixels in ``fig``: per
    pixel column of the figure's width (wider than any of its axes), the first, lowest, highest and
    last sample (M4 aggregation). A line that is not finite everywhere is kept whole."""
    pixels = int(fig.get_figwidth() * fig.dpi)
    if x.size <= 4 * pixels or not (np.isfinite(y).all() and x[-1] > x[0]):
        return x, y
    column = np.minimum(((x - x[0]) * (pixels / (x[-1] - x[0]))).astype(int), pixels - 1)
    first = np.flatnonzero(np.diff(column, prepend=-1))
    last = np.append(first[1:], x.size) - 1
    order = np.lexsort((y, column))  # by column, then by value: a column's lowest first, its highest last
    keep = np.unique(np.concatenate([first, last, order[first], order[last]]))
    return x[keep], y[keep]


def _png(name: str, title: str, fig) -> Figure:
    """The PNG bytes of a drawn figure."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    return Figure(f"{name}.png", title, buffer.getvalue())
