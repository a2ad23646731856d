"""The gap report as a value (:class:`GapReport`), its JSON file and a self-contained Markdown
report with PNG plots.

``gap_report.json`` schema (version 1, documented in the README): ``verdict`` (text) and
``verdict_kind`` (:class:`~.verdict.Verdict` value), ``equations``
(one :class:`EquationGap` each), ``measures`` (``one_step`` and ``free_run`` per data set and
model), ``data``, ``options``, ``config``, ``seconds``.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from ..model import StateModel
from ..outputs import check_folder, one_set, write_atomic
from ..result import _finite
from .verdict import Verdict

SCHEMA_VERSION = 1


@dataclass(frozen=True)
class EquationGap:
    """The diagnosis of one state equation.

    ``significant``: an effect passed the null-verdict rule; ``verdict_kind``: the
    :class:`~.verdict.Verdict`, ``verdict`` its text ('gap explained by <effect>', 'no
    significant gap' or 'gap not explained by the candidate set'); ``effect``: the
    catalogue name of the best hypothesis (or 'power law, no catalogued effect'), None without a
    gap; ``hypothesis``/``exponent``: the winning hypothesis and its fitted exponent;
    ``catalogue_exponent``: the catalogue's total exponent of the named effect (a number, or
    [low, high] for a range; msam_torch/diagnose/catalogue.yaml), else None; ``naming``: for a
    significant gap, how the best hypothesis reads in the catalogue (:mod:`.naming`): ``text``,
    ``total_exponent`` +- ``half_width`` (bootstrap) ``on`` its signal, the entry's ``domain``,
    ``description`` and ``reference``, the ``quantities`` involved and the ``assumed_quantities``
    (undeclared, :mod:`.catalogue`); ``*_equation``: the
    starting, theta-retuned and adapted equations; ``confidence``: ``margin`` (held-out RMSE of
    the best hypothesis with another name, relative), ``runner_up``, ``win_frequency`` over
    ``bootstrap_trials`` and the ``outcomes`` counted; ``improvement``: held-out weak-form RMSE of
    the retuned and adapted models and the rule applied; ``structure_left``: residual structure
    the adapted model leaves, as a share of the retuned model's; ``components``: adjustable
    components ranked by how much their best hypothesis improves; ``ranking``: every valid
    hypothesis, best first; ``where``: flagged fraction, time windows, state regions;
    ``estimator``: the weak form's test functions and the derivative estimator.
    """

    target: str
    significant: bool
    verdict_kind: Verdict
    effect: str | None
    hypothesis: str
    exponent: float | None
    catalogue_exponent: float | list | None
    start_equation: str
    retuned_equation: str
    adapted_equation: str
    confidence: dict
    improvement: dict
    structure_left: float
    components: list
    ranking: list
    where: dict
    estimator: dict
    checks: dict = field(default_factory=dict)  # residual checks of "no significant gap" and the reasons
    naming: dict | None = None

    @property
    def verdict(self) -> str:
        return self.verdict_kind.text(self.effect)


@dataclass(frozen=True)
class GapReport:
    """Where the gap lies, which effect causes it and how far it shrinks; ``str()`` summarises.
    ``verdict_kind``: the :class:`~.verdict.Verdict`; ``verdict``: its text (every explained
    equation's, with remarks)."""

    verdict_kind: Verdict
    verdict: str
    equations: tuple[EquationGap, ...]
    measures: dict
    data: dict
    options: dict
    config: dict
    seconds: float
    reasons: tuple = ()  # why the verdict is inconclusive, and what to try
    series: dict = field(default_factory=dict, repr=False, compare=False)  # arrays for the plots
    models: tuple = field(default=(), repr=False, compare=False)  # per equation: start, retuned, adapted (Eq. 9)

    def model(self, stage: str = "adapted", dtype=torch.float64):
        """The equations of ``stage`` (``start``, ``retuned``, ``adapted``) as an ``nn.Module``
        ``f(t, x)`` for ``torchdiffeq.odeint`` (:meth:`~msam_torch.model.StateModel.from_report`)."""
        return StateModel.from_report(self, stage, dtype)

    def __str__(self) -> str:
        lines = [f"verdict: {self.verdict}"] + [f"  {r}" for r in self.reasons]
        for g in self.equations:
            c = g.confidence
            lines.append(f"{g.target}: {g.verdict}")
            if g.significant:
                named = "" if g.naming is None else f"; {g.naming['text']}"
                boot = (f"; bootstrap wins {100 * c['win_frequency']:.0f} % of {c['bootstrap_trials']}, {_margin(c)}"
                        if c["bootstrap_trials"] else "")
                lines.append(f"  best: {g.hypothesis} ({g.effect}), exponent {g.exponent:.3f}{named}; "
                             f"held-out RMSE -{100 * g.improvement['relative']:.1f} % vs theta re-fitted{boot}")
            lines.append(f"  starting: {g.start_equation}")
            lines.append(f"  theta re-fitted: {g.retuned_equation}")
            lines.append(f"  adapted:  {g.adapted_equation}")
            if g.where["flagged_fraction"] > 0:
                r = g.where["regions"][0]
                lines.append(f"  the {g.where.get('model', 'starting')} model fails where {r['rule']} "
                             f"({100 * r['share']:.0f} % of the record; a separate fit there removes "
                             f"{100 * r['explained']:.0f} % of the squared residual)")
                if g.where.get("model") == "adapted":
                    windows = ", ".join(f"{w['start']:.4g}..{w['stop']:.4g}" for w in g.where["time_windows"][:5])
                    lines.append(f"  remaining gap in time windows {windows}: no candidate adjustment expresses it")
        for label, targets in self.measures.get("one_step", {}).items():
            for target, m in targets.items():
                lines.append(f"one-step sum|eps| of {target} ({label}): start {m['start']['sum_abs_error']:.4g}, "
                             f"theta re-fitted {m['retuned']['sum_abs_error']:.4g}, "
                             f"adapted {m['adapted']['sum_abs_error']:.4g}")
        for label, entry in self.measures.get("free_run", {}).items():
            n = {m: "diverged" if v is None else f"{v:.4g}" for m, v in entry["nrmse"].items()}
            closed = {k: "-" if v is None else f"{100 * v:.0f} %" for k, v in entry["gap_closed"].items()}
            lines.append(f"free-run NRMSE ({label}): start {n['start']}, theta re-fitted {n['retuned']}, "
                         f"adapted {n['adapted']}; closed by retuning {closed['retuning']}, "
                         f"by the effect {closed['effect']}")
        lines.append(f"({self.seconds:.2f} s)")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        out = {"version": SCHEMA_VERSION}
        out.update({k: v for k, v in asdict(self).items() if k not in ("series", "models")})
        out["equations"] = [{**asdict(g), "verdict": g.verdict} for g in self.equations]
        return out

    def save(self, out: str | Path, plots: bool = True) -> Path:
        """Write ``gap_report.json`` and ``report.md`` (with PNGs) into ``out`` as one set (a folder
        renamed into place, :func:`~msam_torch.outputs.one_set`); return the JSON path."""
        out = check_folder(out, "out", is_report_file)
        with one_set(out) as stage:
            write_atomic(stage / "gap_report.json", json.dumps(_finite(self.to_dict()), indent=2))
            write_markdown(self, stage, plots)
        return out / "gap_report.json"


def is_report_file(path: Path) -> bool:
    """A file a gap report writes: a folder it replaces may hold nothing else."""
    return path.is_file() and (path.name in ("gap_report.json", "report.md") or path.suffix == ".png")


def write_markdown(report: GapReport, out: Path, plots: bool = True) -> Path:
    """A self-contained Markdown report next to its PNG plots."""
    figures = _plots(report, out) if plots else {}
    md = ["# Sim-to-real gap report", "", f"**Verdict: {report.verdict}**", ""]
    for g in report.equations:
        md += [f"## {g.target}", "", f"- verdict: {g.verdict}", f"- starting model: `{g.start_equation}`",
               f"- theta re-fitted: `{g.retuned_equation}`", f"- adapted model: `{g.adapted_equation}`"]
        if g.significant:
            c = g.confidence
            md += [f"- which: {g.effect} ({g.hypothesis}, exponent {g.exponent:.3f})"]
            md += _named(g.naming) if g.naming else []
            md += [f"- confidence: wins {100 * c['win_frequency']:.0f} % of {c['bootstrap_trials']} bootstrap trials "
                    f"(time blocks and noise); {_margin(c)} (held-out RMSE); residual structure left "
                    f"{100 * g.structure_left:.0f} %"]
        md += ["", "### Where", "", f"{100 * g.where['flagged_fraction']:.0f} % of the record flagged.", "",
               "| region (best rule per signal) | share of the record | squared residual removed by a separate fit |",
               "|---|---|---|"]
        md += [f"| `{_cell(r['rule'])}` | {100 * r['share']:.0f} % | {100 * r['explained']:.0f} % |" for r in g.where["regions"]]
        md += ["", "| time window | share of residual energy |", "|---|---|"]
        md += [f"| {w['start']:.4g} .. {w['stop']:.4g} | {100 * w['energy_share']:.0f} % |" for w in g.where["time_windows"][:10]]
        if len(g.where["time_windows"]) > 10:
            md += ["", f"({len(g.where['time_windows']) - 10} more windows in gap_report.json)"]
        if g.estimator.get("evaluation") == "simulation":
            md += _simulated_which(g)
        else:
            md += ["", "Components ranked:", "", "| component | best hypothesis | improvement |", "|---|---|---|"]
            md += [f"| `{c['component']}` | `{c['best_hypothesis']}` | {100 * c['improvement']:.1f} % |" for c in g.components]
            md += ["", "### Which: hypotheses by held-out RMSE", "", "| hypothesis | effect | exponent | held-out RMSE | improvement |",
                   "|---|---|---|---|---|"]
            for r in g.ranking[:12]:
                e = "" if r["exponent"] is None else f"{r['exponent']:.3f}"
                md.append(f"| `{r['hypothesis']}` | {r['effect']} | {e} | {r['heldout_rmse']:.4g} | {100 * r['improvement']:.1f} % |")
        md.append("")
        for key in ("residual", "regions"):
            name = figures.get(f"{g.target}_{key}")
            if name:
                md += [f"![{key}]({name})", ""]
    md += ["## How far", "", "| data | measure | model | NRMSE | sum abs error | rho |", "|---|---|---|---|---|---|"]
    for kind in ("one_step", "free_run"):
        for label, entry in report.measures.get(kind, {}).items():
            if kind == "one_step":
                for target, models in entry.items():
                    for m, v in models.items():
                        md.append(f"| {label} | one-step {target} | {m} | {v['nrmse']:.4g} | {v['sum_abs_error']:.4g} | {v['rho']:.4f} |")
            else:
                for state, models in entry["states"].items():
                    for m, v in models.items():
                        md.append(f"| {label} | free-run {state} | {m} | {v['nrmse']:.4g} | {v['sum_abs_error']:.4g} | {v['rho']:.4f} |")
    md.append("")
    for label, entry in report.measures.get("free_run", {}).items():
        closed = entry["gap_closed"]
        text = (f"Free-run NRMSE on {label} data closed by retuning theta: {100 * closed['retuning']:.1f} %, "
                f"by the effect: {100 * closed['effect']:.1f} %")
        if "gap_closed_interval" in entry:
            lo, hi = entry["gap_closed_interval"]["effect"]
            text += f" (bootstrap 90 % interval {100 * lo:.1f} .. {100 * hi:.1f} %)"
        md += [text + ".", ""]
        name = figures.get(f"free_run_{label}")
        if name:
            md += [f"![free run {label}]({name})", ""]
    md += [f"_Computed in {report.seconds:.2f} s._", ""]
    return write_atomic(out / "report.md", "\n".join(md))


def _named(naming: dict) -> list[str]:
    """The catalogue's reading of the best hypothesis: exponent interval, domain, physics, reference,
    and the quantities assumed rather than declared."""
    lines = [f"- catalogue: {naming['text']}"]
    if naming["effect"]:
        lines.append(f"- physics: {naming['description']} (reference: {naming['reference']})")
    if naming["assumed_quantities"]:
        assumed = ", ".join(f"{s} as {q}" for s, q in naming["assumed_quantities"].items())
        lines.append(f"- assumed quantities (not declared in model.quantities): {assumed}")
    return lines


def _simulated_which(g: EquationGap) -> list[str]:
    """Adjusted components with their catalogue names, and the round robin's candidates (evaluated
    by simulation: fitness of the simulated outputs, Eq. 19)."""
    md = ["", "Adjusted components:", "", "| component | adjustment | exponent | effect |", "|---|---|---|---|"]
    md += [f"| `{c['component']}` | `{c['best_hypothesis']}` | {c['exponent']:.3f} | {c['effect']} |" for c in g.components]
    md += ["", "### Which: candidates by fitness of the simulated outputs", "", "| candidate | fitness | exponents | diverged |",
           "|---|---|---|---|"]
    for r in g.ranking[:12]:
        exponents = ", ".join(f"{e:.3f}" for e in r["exponents"])
        md.append(f"| `{_cell(', '.join(r['adjustments']))}` | {r['fitness']:.4g} | {exponents} | {r['diverged']} |")
    return md


def _cell(text: str) -> str:
    """Escape the table separator inside a Markdown table cell."""
    return text.replace("|", "\\|")


def _plots(report: GapReport, out: Path) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = {}
    colours = {"start": "tab:red", "retuned": "tab:orange", "adapted": "tab:green"}
    for target, series in report.series.items():
        where = series.get("where")
        if where is None:
            continue
        t, r, flagged = where["t"].cpu(), where["residual"].cpu(), where["flagged"].cpu()
        fig, ax = plt.subplots(figsize=(8, 3))
        ax.plot(t, r, lw=0.8, color="tab:blue",
                label=f"residual of the {where.get('model', 'starting')} structure fitted where it holds")
        ax.scatter(t[flagged], r[flagged], s=6, color="tab:red", label="flagged")
        ax.set_xlabel("t"), ax.set_ylabel(f"residual of {target}"), ax.legend(fontsize=7)
        names[f"{target}_residual"] = _save(fig, out, f"{target}_residual_time.png")
        values = where["values"]
        if values:
            fig, axes = plt.subplots(1, len(values), figsize=(4 * len(values), 3), squeeze=False)
            for ax, (name, v) in zip(axes[0], values.items()):
                ax.scatter(v.cpu(), r, s=4, c=flagged.float(), cmap="coolwarm")
                ax.set_xlabel(name), ax.set_ylabel("residual")
            names[f"{target}_regions"] = _save(fig, out, f"{target}_residual_vs_state.png")
    for target, series in report.series.items():
        for label in ("train", "held_out"):
            run = series.get(f"free_run_{label}")
            if run is None or f"free_run_{label}" in names:
                continue
            states = list(run["measured"])
            fig, axes = plt.subplots(len(states), 1, figsize=(8, 2.6 * len(states)), squeeze=False)
            for ax, x in zip(axes[:, 0], states):
                ax.plot(run["t"].cpu(), run["measured"][x].cpu(), color="black", lw=1.2, label="measured")
                for k, m in enumerate(("start", "retuned", "adapted")):
                    ax.plot(run["t"].cpu(), run["simulated"][x][k].cpu(), lw=0.9, color=colours[m], label=m)
                ax.set_ylabel(x)
            axes[0, 0].legend(fontsize=7, ncol=4), axes[-1, 0].set_xlabel("t")
            names[f"free_run_{label}"] = _save(fig, out, f"free_run_{label}.png")
    return names


def _margin(confidence: dict) -> str:
    """The held-out RMSE margin to the best hypothesis with another name, if there is one."""
    if confidence["runner_up"] is None:
        return "no competing hypothesis with another name"
    return f"margin {100 * confidence['margin']:.1f} % to {confidence['runner_up']}"


def _save(fig, out: Path, name: str) -> str:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(out / name, dpi=90)  # into the set's staging folder (GapReport.save)
    plt.close(fig)
    return name

