"""Does ``msam run``'s adapted structure say what the diagnosis says? One answer for one record.

``msam run`` adapts each adjustable component in place by a power law of a signal (the paper's
Eq. 8, Algorithm 1), chosen by its fitness on the training rows. The diagnosis also tries a copy
beside a component, a constant and exchange laws, judges them on held-out rows and names the
winner only within its exponent's interval. The two agree on an equation when run changed exactly
one component (an exponent beyond the catalogue's resolution) and its total exponent on the signal
the diagnosis named lies within the diagnosis's interval: the same law, whatever its form (a
Torricelli outflow written ``h|h|^-0.5`` in place, or as a copy beside the linear outflow). Otherwise
the run's output states the diagnosis's reading and why its own differs."""
from __future__ import annotations

from pathlib import Path

from msam_torch.config.schema import Config
from msam_torch.config.to_spec import to_spec
from msam_torch.diagnosis.catalogue.entries import TOLERANCE, power_in
from msam_torch.diagnosis.compare.verdict import Verdict
from msam_torch.diagnosis.report.gap_report import GapReport
from msam_torch.errors import MSAMError, NoInformation, Uninformative
from msam_torch.run.progress import LOGGER
from msam_torch.run.result import RunResult

WHY = {"additive": "the diagnosis keeps the component and adds a copy of it with its own exponent",
       "exchange": "the diagnosis adds an exchange law (a copy with a constant and the reference's square)",
       "offset": "the diagnosis adds a constant, which run's candidates do not hold",
       "multiplicative": "the diagnosis judges the candidates on held-out rows, run by their fitness on the "
                         "training rows"}


def changed(result: RunResult, config: Config) -> dict[str, list[tuple[str, str, float | None]]]:
    """Per target, the components run adjusted: (term, signal of the adjustment, its exponent, the
    total exponent on the signal or None where the term is not a power of that signal)."""
    spec = to_spec(config.model)
    out = {}
    for equation, entry in zip(spec.equations, result.equations):
        functions = {f.text: f for f in equation.adjustments}
        rows = []
        for component, f, gamma in zip(equation.components, entry.adjustments, entry.exponents):
            if f is None or gamma is None:
                continue
            signal = functions[f].inner_text
            power = power_in(component.term, signal)
            rows.append((component.term.text, signal, gamma, None if power is None else power + gamma))
        out[entry.target] = rows
    return out


def agreement(result: RunResult, report: GapReport, config: Config) -> list[str]:
    """Lines for ``msam run``'s output: per equation whose diagnosis names an effect, whether run's
    adapted structure reads the same law, and if not, the diagnosis's reading and why it differs;
    per equation with another verdict, that verdict and its model."""
    lines = []
    runs = changed(result, config)
    for gap in report.equations:
        mine = [row for row in runs.get(gap.target, []) if abs(row[2]) > TOLERANCE]  # changed beyond resolution
        naming = gap.naming or {}
        reading = f"{gap.target}: diagnosis: {gap.verdict}"
        if gap.verdict_kind is not Verdict.EXPLAINED:
            lines.append(reading + ("" if gap.verdict_kind is Verdict.NO_GAP else f"; its model: {gap.adapted_equation}"))
            continue
        total, half, signal = naming.get("total_exponent"), naming.get("half_width"), naming.get("on")
        same = (total is not None and len(mine) == 1 and mine[0][1] == signal and mine[0][3] is not None
                and abs(mine[0][3] - total) <= half)
        if same:
            lines.append(f"{reading}: run's adapted structure reads the same law (total exponent {mine[0][3]:.3g} "
                         f"on {signal}, within {total:.3g} ± {half:.2g})")
            continue
        ran = "; ".join(f"{term} by |{s}|^{gamma:.3g}" for term, s, gamma, _ in runs.get(gap.target, [])
                        if abs(gamma) > 1e-3)
        lines.append(f"{reading} ({naming.get('text', gap.effect)}); its model: {gap.adapted_equation}")
        lines.append(f"  run's adapted structure differs (it adjusted {ran or 'no component'}): "
                     f"{WHY.get(gap.kind, WHY['multiplicative'])}; the diagnosis judges its reading on held-out rows "
                     "and names it only within its interval")
    return lines


def stated(config: Config, result: RunResult, base_dir: Path | None = None, path: Path | None = None) -> list[str]:
    """``msam run``'s closing lines on measured data evaluated algebraically: the diagnosis of the
    same record (its default options) and :func:`agreement`; none for a simulated system or a run
    evaluated by simulation. A record that tells nothing for a target makes the run's result carry
    no information (:class:`~msam_torch.errors.NoInformation`; ``path``: the result written)."""
    if config.data.system is not None or config.adaptation.evaluation == "simulation":
        return []
    from msam_torch.diagnosis.stages.pipeline import diagnose

    LOGGER.info("diagnosing the same record (--no-diagnosis skips it)")
    try:
        report = diagnose(config, base_dir=base_dir)
    except Uninformative as exc:
        raise NoInformation(f"{exc}; the adapted model carries no information{f' ({path} records the run)' if path else ''}")
    except MSAMError as exc:
        return [f"diagnosis: none ({exc})"]
    return agreement(result, report, config)
