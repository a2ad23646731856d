"""The gap report as a Markdown document: verdict and a plain-language summary (:mod:`.summary`),
then per equation the models, parameter and exponent intervals, where, which, the residual checks
with their figures; then how far.

Tables are clean: rows that read the same are shown once, zero-length time windows (single
flagged samples) are summarised in one line instead of listed, and an interval wider than its
value says that the data do not determine it. The hypotheses' rows are told apart by their kind
and, for a form fitted from several starting exponents, the start each row's fit began at.
"""
from __future__ import annotations

from msam_torch.diagnosis.report.figures import Figure, correlations, residuals
from msam_torch.diagnosis.report.summary import summary
from msam_torch.diagnosis.report.units import Units

WINDOWS = 10  # time windows listed, at most
HYPOTHESES = 12  # ranked hypotheses listed, at most
MODEL_NAMES = {"start": "starting", "retuned": "theta re-fitted", "adapted": "adapted"}


def markdown(report, figures: list[Figure]) -> str:
    """The report (a :class:`~msam_torch.diagnosis.report.gap_report.GapReport`) as Markdown, its figures referenced by file name."""
    shown, units = {f.name: f for f in figures}, Units(report.config)
    md = ["# Sim-to-real gap report", "", f"**Verdict: {report.verdict}**", ""]
    md += [f"- {reason}" for reason in report.reasons] + ([""] if report.reasons else [])
    md += ["## Summary", ""] + [p for text in summary(report) for p in (text, "")]
    for g in report.equations:
        md += _equation(g, report.series.get(g.target, {}), units, shown)
    md += _how_far(report.measures)
    for label in ("train", "held_out"):
        md += _images(shown, f"free_run_{label}", f"frequency_response_{label}")
    md += _in_turn(report.in_turn)
    md += [f"_Computed in {report.seconds:.2f} s._", ""]
    return "\n".join(md)


def _in_turn(in_turn: dict) -> list[str]:
    """The effects added in turn (:mod:`msam_torch.diagnosis.effects.multi`), each with the held-out errors before and after it."""
    if not in_turn.get("effects"):
        return []
    md = ["## Effects in turn", "", "| step | equation | effect | gamma | held-out RMSE before -> after | "
          "free-run NRMSE before -> after |", "|---|---|---|---|---|---|"]
    for e in in_turn["effects"]:
        free = " -> ".join("-" if v is None else f"{v:.4g}" for v in (e["free_run_nrmse"]["before"], e["free_run_nrmse"]["after"]))
        exponent = exponent_text(e["exponent"]).removeprefix("gamma ")
        md.append(f"| {e['step']} | {e['target']} | {e['effect']} | {exponent} | "
                  f"{e['heldout_rmse']['before']:.4g} -> {e['heldout_rmse']['after']:.4g} | {free} |")
    return md + ["", f"Stopped: {in_turn['stopped']}.", ""]


def exponent_text(value: float | None) -> str:
    """``gamma 1.993`` (the exponent fitted in the hypothesis's slot), or ``no exponent`` (an offset)."""
    return "no exponent" if value is None else f"gamma {value:.3f}"


def interval_text(low: float, high: float, value: float, scale: float = 1.0, unit: str = "") -> str:
    """``low to high`` (times ``scale``, with ``unit``), with a comment when the interval is wider
    than the value it brackets."""
    text = f"{scale * low:.4g} to {scale * high:.4g}{unit}"
    return text + (": not determined by these data" if high - low > abs(value) else "")


def unique_rows(rows: list[str]) -> list[str]:
    """Table rows in order, each text once."""
    return list(dict.fromkeys(rows))


def _equation(g, series: dict, units: Units, shown: dict) -> list[str]:
    """One equation's section, each figure beside the text it illustrates."""
    md = [f"## {g.target}", "", f"- verdict: {g.verdict}", f"- starting model: `{g.start_equation}`",
          f"- theta re-fitted: `{g.retuned_equation}`", f"- adapted model: `{g.adapted_equation}`"]
    if g.significant:
        c = g.confidence
        md += [f"- which: {g.effect} ({g.hypothesis}, {exponent_text(g.exponent)})"]
        md += _named(g.naming) if g.naming else []
        if c["bootstrap_trials"]:
            md += [f"- confidence: wins {100 * c['win_frequency']:.0f} % of {c['bootstrap_trials']} bootstrap trials "
                   f"(time blocks and noise); {margin(c)} (held-out RMSE); residual structure left "
                   f"{100 * g.structure_left:.0f} %"]
        if c.get("rival_equation"):
            md += [f"- rival, {c['rival']}: `{c['rival_equation']}`"]
    md += [f"- {reason}" for reason in g.checks.get("reasons", [])]
    md += [""] + _intervals(getattr(g, "intervals", None) or [])
    md += _where(g.where, units) + _images(shown, f"{g.target}_residual_time", f"{g.target}_residual_vs_state")
    md += _simulated_which(g) if g.estimator.get("evaluation") == "simulation" else _which(g)
    md += _residual_checks(g, series, units) + _images(shown, f"{g.target}_residual_correlation")
    return md


def _intervals(terms: list[dict]) -> list[str]:
    if not terms:
        return []
    md = ["### Parameters of the adapted model", "", "90 % bootstrap intervals (time blocks and noise re-drawn).", "",
          "| term | coefficient | 90 % interval | exponent | 90 % interval |", "|---|---|---|---|---|"]
    rows, seen = [], {}
    for t in terms:
        seen[t["term"]] = seen.get(t["term"], 0) + 1  # a component split into copies: each copy its row
        name = f"`{_cell(t['term'])}`" + (f" (copy {seen[t['term']]})" if seen[t["term"]] > 1 else "")
        theta = "-" if t["theta_interval"] is None else interval_text(*t["theta_interval"], t["theta"])
        exponent, spread = "", ""
        if t["exponent"] is not None:
            exponent = f"{t['exponent']:.3f}"
            spread = "-" if t["exponent_interval"] is None else "{:.3f} to {:.3f}".format(*t["exponent_interval"])
        rows.append(f"| {name} | {t['theta']:.4g} | {theta} | {exponent} | {spread} |")
    return md + rows + [""]


def _where(where: dict, units: Units) -> list[str]:
    md = ["### Where", "", f"{100 * where['flagged_fraction']:.0f} % of the record flagged"
          + (f" (the {where['model']} model)." if where.get("model") else "."), ""]
    if where.get("note"):
        md += [where["note"] + ".", ""]
    if where["regions"]:
        md += ["| region (best rule per signal) | share of the record | squared residual removed by a separate fit |",
               "|---|---|---|"]
        md += unique_rows([f"| `{_cell(r['rule'])}` | {100 * r['share']:.0f} % | {100 * r['explained']:.0f} % |"
                           for r in where["regions"]]) + [""]
    windows = [w for w in where["time_windows"] if w["stop"] > w["start"]]
    single = [w for w in where["time_windows"] if w["stop"] <= w["start"]]
    if windows:
        md += [f"| time window ({units.times}) | share of residual energy |", "|---|---|"]
        md += unique_rows([f"| {w['start']:.4g} .. {w['stop']:.4g} | {_percent(w['energy_share'])} |"
                           for w in windows[:WINDOWS]]) + [""]
    if len(windows) > WINDOWS:
        md += [f"{len(windows) - WINDOWS} more windows in gap_report.json.", ""]
    if single:
        share = sum(w["energy_share"] for w in single)
        md += [f"{len(single)} isolated flagged samples (no window; {_percent(share)} of the residual energy) "
               "are not listed.", ""]
    return md


def _which(g) -> list[str]:
    md = ["### Which: hypotheses by held-out RMSE", "", "| component | best hypothesis | improvement |", "|---|---|---|"]
    md += unique_rows([f"| `{c['component']}` | `{_cell(c['best_hypothesis'])}` | {100 * c['improvement']:.1f} % |"
                       for c in g.components]) + [""]
    md += ["| hypothesis | kind | effect | gamma | held-out RMSE | improvement |", "|---|---|---|---|---|---|"]
    rows = []
    for r in g.ranking:
        e = "" if r["exponent"] is None else f"{r['exponent']:.3f}"
        rows.append(f"| `{_cell(r['hypothesis'])}` | {_kind(r)} | {r['effect']} | {e} | {r['heldout_rmse']:.4g} | "
                    f"{100 * r['improvement']:.1f} % |")
    rows = unique_rows(rows)
    md += rows[:HYPOTHESES] + [""]
    if any(r.get("start") is not None for r in g.ranking):
        md += [("An additive (or exchange) form is fitted from several starting values of gamma ('from'), each "
                "its own row: starts that end at the same gamma found the same fit."), ""]
    return md + ([f"{len(rows) - HYPOTHESES} more hypotheses in gap_report.json.", ""] if len(rows) > HYPOTHESES else [])


def _kind(row: dict) -> str:
    """What a ranking row changes: ``multiplicative``, ``additive, from gamma = 0.5``, ..."""
    kind = {"retuned": "theta re-fitted only", "offset": "constant added"}.get(row["kind"], row["kind"])
    return kind + ("" if row.get("start") is None else f", from gamma = {row['start']:g}")


def _simulated_which(g) -> list[str]:
    """Adjusted components with their catalogue names, and the round robin's candidates (evaluated
    by simulation: fitness of the simulated outputs, Eq. 19)."""
    md = ["### Which: candidates by fitness of the simulated outputs", "",
          "| component | adjustment | exponent | effect |", "|---|---|---|---|"]
    md += unique_rows([f"| `{c['component']}` | `{_cell(c['best_hypothesis'])}` | {c['exponent']:.3f} | {c['effect']} |"
                       for c in g.components]) + [""]
    md += ["| candidate | fitness | exponents | diverged |", "|---|---|---|---|"]
    rows = unique_rows([f"| `{_cell(', '.join(r['adjustments']))}` | {r['fitness']:.4g} | "
                        f"{', '.join(f'{e:.3f}' for e in r['exponents'])} | {r['diverged']} |" for r in g.ranking])
    return md + rows[:HYPOTHESES] + [""]


def _residual_checks(g, series: dict, units: Units) -> list[str]:
    """The residual's autocorrelation and cross-correlation with the inputs against the 95 %
    white-noise band, per model."""
    found = residuals(g.target, series, g.estimator)
    if found is None:
        return []
    source, by_model, inputs, spacing = found
    md = ["### Residual checks", "", f"The {source}, a sample every {spacing:.3g} {units.times}: share of lags 1..L "
          "outside the 95 % band ±1.96/√N (a white residual leaves about 5 % outside).", ""]
    names = sorted(inputs)
    md += ["| model | N | L | band | autocorrelation outside | " + " | ".join(f"correlation with {u} outside"
                                                                         for u in names) + " |",
           "|---" * (5 + len(names)) + "|"]
    for m, r in by_model.items():
        c = correlations(r, inputs)
        outside = lambda v: f"{100 * (abs(v) > c['band']).mean():.0f} %"
        cross = [outside(c["ccf"][u]) if u in c["ccf"] else "-" for u in names]
        md.append(f"| {MODEL_NAMES[m]} | {c['n']} | {c['lags']} | {c['band']:.3f} | {outside(c['acf'][1:])} | "
                  + " | ".join(cross) + " |")
    return md + [""]


def _how_far(measures: dict) -> list[str]:
    md = ["## How far", "", "| record | measure | NRMSE starting | NRMSE theta re-fitted | NRMSE adapted | "
          "rho starting | rho theta re-fitted | rho adapted |", "|---|---|---|---|---|---|---|---|"]
    rows = []
    for label, entry in measures.get("one_step", {}).items():
        rows += [_measure_row(label, f"one-step {target}", models) for target, models in entry.items()]
    for label, entry in measures.get("free_run", {}).items():
        rows += [_measure_row(label, f"free-run {state}", models) for state, models in entry["states"].items()]
    md += unique_rows(rows) + [""]
    for label, entry in measures.get("free_run", {}).items():
        closed = entry["gap_closed"]
        text = (f"Free-run NRMSE on the {label.replace('_', '-')} record closed by retuning theta: "
                f"{_percent(closed['retuning'])}, by the effect: {_percent(closed['effect'])} "
                f"({_percent(closed['effect_on_retuned'])} of the theta re-fitted model's)")
        if "gap_closed_interval" in entry:
            text += f" (bootstrap 90 % interval {interval_text(*entry['gap_closed_interval']['effect'], closed['effect'], 100, ' %')})"
        md += [text + ".", ""]
    return md


def _measure_row(label: str, measure: str, models: dict) -> str:
    cells = [f"{models[m]['nrmse']:.4g}" for m in MODEL_NAMES] + [f"{models[m]['rho']:.4f}" for m in MODEL_NAMES]
    return f"| {label.replace('_', '-')} | {measure} | " + " | ".join(cells) + " |"


def _images(shown: dict, *names: str) -> list[str]:
    md = []
    for name in names:
        figure = shown.get(f"{name}.png")
        if figure is not None:
            md += [f"![{figure.title}]({figure.name})", ""]
    return md


def _named(naming: dict) -> list[str]:
    """The catalogue's reading of the best hypothesis: exponent interval, domain, physics, reference,
    and the quantities assumed rather than declared."""
    lines = [f"- catalogue: {naming['text']}"]
    if naming["effect"]:
        lines.append(f"- physics: {naming['description']} (reference: {naming['reference']})")
    if naming.get("at_catalogue_exponent"):
        lines.append(f"- at the catalogue exponent: `{naming['at_catalogue_exponent']}`")
    if naming["assumed_quantities"]:
        assumed = ", ".join(f"{s} as {q}" for s, q in naming["assumed_quantities"].items())
        lines.append(f"- assumed quantities (not declared in model.quantities): {assumed}")
    return lines


def margin(confidence: dict) -> str:
    """The held-out RMSE margin to the best effect hypothesis with another name, if there is one,
    and how often the rival (that one, or one held at a catalogue exponent) predicts as well on
    held-out rows and within the margin on cross-fitted training rows (:func:`~msam_torch.diagnosis.compare.confidence.apart`)."""
    rival, runner = confidence.get("rival"), confidence["runner_up"]
    if runner is None and rival is None:
        return "no competing hypothesis with another name"
    text = "no other fitted effect with another name" if runner is None else \
        f"margin {100 * confidence['margin']:.1f} % to {runner}"
    if rival is None:
        return text
    who = ", it" if rival == runner else f"; {rival}"
    held, training = 100 * confidence["apart_p_held_out"], 100 * confidence["apart_p_training"]
    return (f"{text}{who} as good in {held:.0f} % of held-out resamples and within the margin in {training:.0f} % "
            "of cross-fitted training ones")


def _percent(share: float) -> str:
    """A share in per cent; one decimal below 10 %, so that a small share does not read '0 %'."""
    return f"{100 * share:.{0 if abs(share) >= 0.1 else 1}f} %"


def _cell(text: str) -> str:
    """Escape the table separator inside a Markdown table cell."""
    return text.replace("|", "\\|")
