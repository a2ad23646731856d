"""The gap report as a value (:class:`GapReport`) and its files: ``gap_report.json``, the
Markdown report with its PNG figures (:mod:`.document`, :mod:`.figures`), the same report as one
self-contained HTML file (:mod:`.html`) and, on request, TensorBoard event files.

``gap_report.json`` (version 1): ``verdict`` (text) and ``verdict_kind`` (:class:`~msam_torch.diagnosis.compare.verdict.Verdict`
value), ``equations`` (one :class:`EquationGap` each, its records typed in :mod:`.records`),
``measures`` (``one_step`` and ``free_run`` per data set and model), ``data``, ``options``,
``config``, ``seconds``; its JSON schema is generated from these types (:mod:`.json_schema`).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import torch

from msam_torch.diagnosis.compare.verdict import Verdict
from msam_torch.diagnosis.report.document import exponent_text, margin, markdown
from msam_torch.diagnosis.report.figures import render
from msam_torch.diagnosis.report.html import page
from msam_torch.diagnosis.report.records import Checks, Confidence, Estimator, Improvement, InTurn, Naming, Where
from msam_torch.diagnosis.report.summary import summary
from msam_torch.diagnosis.report.units import Units
from msam_torch.run.outputs import check_folder, one_set, write_atomic
from msam_torch.run.result import _finite
from msam_torch.run.state_model import StateModel
from msam_torch.run.tracking import TensorBoardTracker

SCHEMA_VERSION = 1


@dataclass(frozen=True)
class EquationGap:
    """The diagnosis of one state equation.

    ``significant``: an effect passed the null-verdict rule; ``verdict_kind``: the
    :class:`~msam_torch.diagnosis.compare.verdict.Verdict`, ``verdict`` its text ('gap explained by <effect>', 'no
    significant gap' or 'gap not explained by a catalogued effect'); ``effect``: the
    catalogue name of the best hypothesis (or 'power law, no catalogued effect'), None without a
    gap; ``hypothesis``/``exponent``: the winning hypothesis and its fitted exponent;
    ``catalogue_exponent``: the catalogue's total exponent of the named effect (a number, or
    [low, high] for a range; msam_torch/diagnosis/catalogue/catalogue.yaml), else None; ``naming``: for a
    significant gap, how the best hypothesis reads in the catalogue (:mod:`msam_torch.diagnosis.catalogue.naming`): ``text``,
    ``total_exponent`` +- ``half_width`` (bootstrap) ``on`` its signal, the entry's ``domain``,
    ``description`` and ``reference``, the ``quantities`` involved, the ``assumed_quantities``
    (undeclared, :mod:`msam_torch.diagnosis.catalogue.entries`) and the equation ``at_catalogue_exponent`` (the best
    hypothesis held at its entry's exponent, theta re-fitted; None without one); ``*_equation``: the
    starting, theta-retuned and adapted equations; ``confidence``: ``margin`` (held-out RMSE of
    the best hypothesis with another name, relative), ``runner_up``, the ``rival`` hardest to tell
    apart on out-of-sample rows and ``apart_p``, ``apart_p_held_out``, ``apart_p_training``
    (:func:`~msam_torch.diagnosis.compare.confidence.apart`),
    ``win_frequency`` over ``bootstrap_trials`` and the ``outcomes`` counted; ``improvement``: held-out weak-form RMSE of
    the retuned and adapted models and the rule applied; ``structure_left``: residual structure
    the adapted model leaves, as a share of the retuned model's; ``components``: adjustable
    components ranked by how much their best hypothesis improves; ``ranking``: every valid
    hypothesis, best first (``start``: the exponent an additive or exchange fit started from); ``where``: flagged fraction, time windows, state regions;
    ``estimator``: the weak form's test functions and the derivative estimator; ``intervals``:
    each term of the adapted model with its coefficient and exponent and their 90 % bootstrap
    intervals (:mod:`msam_torch.diagnosis.compare.intervals`; empty without bootstrap trials' fits).
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
    confidence: Confidence
    improvement: Improvement
    structure_left: float
    components: list
    ranking: list
    where: Where
    estimator: Estimator
    checks: Checks = field(default_factory=dict)  # residual checks of "no significant gap" and the reasons
    naming: Naming | None = None
    intervals: list = field(default_factory=list)

    @property
    def verdict(self) -> str:
        return self.verdict_kind.text(self.effect)

    @property
    def kind(self) -> str | None:
        """The kind of the winning hypothesis (``multiplicative``, ``additive``, ...): its row of
        ``ranking``, which lists every valid hypothesis by held-out RMSE, the winner not always first."""
        return next((r.get("kind") for r in self.ranking if r.get("hypothesis") == self.hypothesis), None)


@dataclass(frozen=True)
class GapReport:
    """Where the gap lies, which effect causes it and how far it shrinks; ``str()`` summarises (the
    plain-language summary, :mod:`.summary`, then the numbers).
    ``verdict_kind``: the :class:`~msam_torch.diagnosis.compare.verdict.Verdict`; ``verdict``: its text (every explained
    equation's, with remarks)."""

    verdict_kind: Verdict
    verdict: str
    equations: tuple[EquationGap, ...]
    measures: dict
    data: dict
    options: dict
    config: dict
    seconds: float
    reasons: tuple[str, ...] = ()  # why the verdict is inconclusive, and what to try
    in_turn: InTurn = field(default_factory=dict)  # effects added in turn, why the loop stopped, the model with every accepted effect (.multi)
    series: dict = field(default_factory=dict, repr=False, compare=False)  # arrays for the plots
    models: tuple = field(default=(), repr=False, compare=False)  # per equation: start, retuned, adapted (Eq. 9)
    accepted: dict = field(default_factory=dict, repr=False, compare=False)  # effects in turn: config, models, stages

    def model(self, stage: str = "adapted", dtype=torch.float64):
        """The equations of ``stage`` (``start``, ``retuned``, ``adapted``, or ``accepted``: every effect
        added in turn) as an ``nn.Module`` ``f(t, x)`` for ``torchdiffeq.odeint``
        (:meth:`~msam_torch.run.state_model.StateModel.from_report`)."""
        return StateModel.from_report(self, stage, dtype)

    def __str__(self) -> str:
        lines = [f"verdict: {self.verdict}"] + [f"  {r}" for r in self.reasons]
        lines += ["summary:"] + [f"  {text}" for text in summary(self)] + ["numbers:"]
        for g in self.equations:
            c = g.confidence
            lines.append(f"{g.target}: {g.verdict}")
            if g.significant:
                named = "" if g.naming is None else f"; {g.naming['text']}"
                boot = (f"; bootstrap wins {100 * c['win_frequency']:.0f} % of {c['bootstrap_trials']}, {margin(c)}"
                        if c["bootstrap_trials"] else "")
                lines.append(f"  best: {g.hypothesis} ({g.effect}), {exponent_text(g.exponent)}{named}; "
                             f"held-out RMSE -{100 * g.improvement['relative']:.1f} % vs theta re-fitted{boot}")
            lines.append(f"  starting: {g.start_equation}")
            lines.append(f"  theta re-fitted: {g.retuned_equation}")
            lines.append(f"  adapted:  {g.adapted_equation}")
            if g.verdict_kind == Verdict.EXPLAINED and (g.naming or {}).get("at_catalogue_exponent"):
                lines.append(f"  at the catalogue exponent: {g.naming['at_catalogue_exponent']}")
            if g.significant and g.verdict_kind == Verdict.INCONCLUSIVE and c.get("rival_equation"):
                lines.append(f"  as good, {c['rival']}: {c['rival_equation']}")
            if g.where["flagged_fraction"] > 0 and g.verdict_kind != Verdict.NO_GAP:  # no gap: nothing to locate
                r = g.where["regions"][0]
                lines.append(f"  the {g.where.get('model', 'starting')} model fails where {r['rule']} "
                             f"({100 * r['share']:.0f} % of the record; a separate fit there removes "
                             f"{100 * r['explained']:.0f} % of the squared residual)")
                if g.where.get("model") == "adapted":
                    windows = ", ".join(f"{w['start']:.4g}..{w['stop']:.4g}" for w in g.where["time_windows"][:5])
                    lines.append(f"  remaining gap in time windows {windows}: no candidate adjustment expresses it")
        for label, targets in self.measures.get("one_step", {}).items():
            for target, m in targets.items():
                lines.append(f"one-step sum|eps| of {target} against its estimate ({label}): "
                             f"start {m['start']['sum_abs_error']:.4g}, "
                             f"theta re-fitted {m['retuned']['sum_abs_error']:.4g}, "
                             f"adapted {m['adapted']['sum_abs_error']:.4g}")
        for label, entry in self.measures.get("free_run", {}).items():
            n = {m: "diverged" if v is None else f"{v:.4g}" for m, v in entry["nrmse"].items()}
            closed = {k: "-" if v is None else f"{100 * v:.0f} %" for k, v in entry["gap_closed"].items()}
            lines.append(f"free-run NRMSE ({label}): start {n['start']}, theta re-fitted {n['retuned']}, "
                         f"adapted {n['adapted']}; closed by retuning {closed['retuning']}, "
                         f"by the effect {closed['effect']} ({closed['effect_on_retuned']} of theta re-fitted's)")
        for e in self.in_turn.get("effects", []):
            lines.append(f"effect {e['step']} in {e['target']}: {e['effect']} ({exponent_text(e['exponent'])}); "
                         f"held-out RMSE {e['heldout_rmse']['before']:.4g} -> {e['heldout_rmse']['after']:.4g}")
        if self.in_turn:
            lines.append(f"effects in turn stopped: {self.in_turn['stopped']}")
        lines.append(f"(diagnosis {self.seconds:.2f} s, reading the data and writing the report not counted)")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        out = {"version": SCHEMA_VERSION}
        arrays = replace(self, series={}, models=(), accepted={})  # not in the JSON: not copied by asdict either
        out.update({k: v for k, v in asdict(arrays).items() if k not in ("series", "models", "accepted")})
        out["equations"] = [{**asdict(g), "verdict": g.verdict} for g in self.equations]
        return out

    def save(self, out: str | Path, plots: bool = True, tensorboard: bool = False) -> Path:
        """Write ``gap_report.json``, ``report.md`` with its PNG figures and ``report.html`` (the
        figures embedded) into ``out`` as one set (a folder renamed into place,
        :func:`~msam_torch.run.outputs.one_set`), with ``tensorboard``: event files in
        ``out/tensorboard`` (:meth:`~msam_torch.run.tracking.TensorBoardTracker.log_diagnosis`); return
        the JSON path."""
        out = check_folder(out, "out", is_report_file)
        figures = render(self, Units(self.config)) if plots else []
        with one_set(out) as stage:
            write_atomic(stage / "gap_report.json", json.dumps(_finite(self.to_dict()), indent=2))
            for figure in figures:
                (stage / figure.name).write_bytes(figure.png)
            text = markdown(self, figures)
            write_atomic(stage / "report.md", text)
            write_atomic(stage / "report.html", page(text, figures))
            if tensorboard:
                tracker = TensorBoardTracker(stage / "tensorboard")
                tracker.log_diagnosis(self, figures)
                tracker.close()
        return out / "gap_report.json"


def is_report_file(path: Path) -> bool:
    """A file a gap report writes: a folder it replaces may hold nothing else."""
    if path.is_dir():
        return path.name == "tensorboard" and all(p.is_file() and p.name.startswith("events.out.tfevents.")
                                                  for p in path.iterdir())
    return path.is_file() and (path.name in ("gap_report.json", "report.md", "report.html") or path.suffix == ".png")


