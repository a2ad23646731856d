"""The generated zoo of withheld-effect cases (:mod:`msam_torch.zoo`) through ``msam diagnose``,
beside a PySINDy discrepancy baseline on the same cases.

Each seed draws a case (domain, system, parameters, units, excitation, measured subset, noise,
withheld effect or none); the case is written to CSV files in a temporary folder and diagnosed
from those paths (:func:`run_diagnosis`, the one place that knows the signature of
:func:`msam_torch.diagnosis.diagnose`). Scored by :mod:`msam_torch.zoo.score`: strict top-1 on
catalogued cases, "no significant gap" on null cases, re-fitted theta within 3 % of the truth
(null cases, noise <= 1 %), re-fitted start no worse than the nominal one in held-out free run,
diverged free runs beside a verdict other than "inconclusive", and confident wrong names on
out-of-catalogue cases. Issue 54's acceptance figures come first: on catalogued cases whose
record pins the true law (the oracle, :mod:`msam_torch.zoo.oracle`), top-1; on all cases, wrong
names; "no significant gap" beside the report's own evidence of a gap; and ``msam run`` on every
case the diagnosis names an effect in (:mod:`msam_torch.zoo.one_answer`, about 0.3 s a case).
The baseline (:mod:`msam_torch.zoo.sindy`) is scored with the same strict top-1, null and
wrong-name rules.

Seeds: the zoo, the scores and the baseline were written on seeds 0-199, later changes were
developed on 6300-6599 (the systems on differences, the oracle and run's agreement on 6300-6325,
the tests' cases found among 0-80 of single domains); each published figure names seeds that were
not looked at before it (docs/diagnose.md, "Generated cases"; the zoo page: 50000-50299).

Run (report: 300 cases; about 5-10 s per case and process, one process per CPU):
    python -m experiments.suites.zoo --cases 300 --seed-start 1000 [--timeout 120] [--out runs/zoo.jsonl]
Options: --noise 0.01 0.05 (cycle these levels instead of drawing), --domains mechanical thermal,
--no-sindy, --max-new N (diagnose at most N cases not in ``--out``; 0 tabulates what it holds),
--workers N (processes side by side, one torch thread each; default: the CPUs; rows are written as
they finish and tabulated in seed order).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402

from msam_torch.diagnosis import diagnose  # noqa: E402
from msam_torch.engine.allocator import keep_freed_memory  # noqa: E402
from msam_torch.run.result import _finite  # noqa: E402
from msam_torch.zoo import DOMAINS, generate, oracle, score, sindy  # noqa: E402
from msam_torch.zoo.one_answer import one_answer

LOW_NOISE = 0.01  # "<= 1 % noise" rows of the acceptance figures


def run_diagnosis(config: Path, train: Path, validation: Path):
    """``diagnose`` on a case written to files."""
    return diagnose(config, data=train, validation=validation)


def _naming(gap) -> dict | None:
    """What a flagged equation's name rests on: total exponent, its bootstrap half-width, the
    catalogue's exponent, the bootstrap trials' outcomes and the rival told apart on out-of-sample rows."""
    if gap.naming is None:
        return None
    keys = ("effect", "total_exponent", "half_width", "catalogue_exponent")
    told = ("win_frequency", "outcomes", "rival", "apart_p", "apart_p_held_out", "apart_p_training")
    return {**{k: gap.naming.get(k) for k in keys}, **{k: gap.confidence.get(k) for k in told}}


class Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise Timeout()


def _attempt(function, *arguments):
    """``function(*arguments)``, or its error as a finding."""
    try:
        return function(*arguments)
    except Exception as exc:  # noqa: BLE001 (a check the case fails is a finding, not a crash of the run)
        return {"error": f"{type(exc).__name__}: {exc}".splitlines()[0][:300]}


def run_case(seed: int, args) -> dict:
    """Generate, diagnose and score one case (and the baseline); a row of the tables."""
    noise = args.noise[seed % len(args.noise)] if args.noise else None
    started = time.perf_counter()
    case = generate(seed, tuple(args.domains) if args.domains else None, noise)
    row = {"seed": seed, "domain": case.metadata["domain"], "system": case.metadata["system"],
           "noise": case.metadata["noise"], "measured": case.metadata["measured"], "truth": case.truth,
           "generate_s": time.perf_counter() - started}
    signal.alarm(args.timeout)
    try:
        with tempfile.TemporaryDirectory() as folder:
            config = case.write(folder)
            started = time.perf_counter()
            report = run_diagnosis(config, Path(folder) / "train.csv", Path(folder) / "validation.csv")
            row["diagnose_s"] = time.perf_counter() - started
            row["ours"] = score.score(report, case.truth)
            row["ours"]["equations"] = {g.target: {"verdict": g.verdict, "hypothesis": g.hypothesis,
                                                   "exponent": g.exponent, "naming": _naming(g)}
                                        for g in report.equations}
            signal.alarm(args.timeout)  # msam run and the oracle: their own time
            started = time.perf_counter()
            row["ours"]["one_answer"] = _attempt(one_answer, config, report)
            if case.truth["kind"] == "catalogued":
                row["oracle"] = _attempt(oracle.identifiable, case.config, case.truth, case.train, case.validation)
            row["checks_s"] = time.perf_counter() - started
    except Timeout:
        row["ours"] = {"error": f"timeout after {args.timeout} s"}
    except Exception as exc:  # a case the diagnosis cannot take is a finding, not a crash of the run
        row["ours"] = {"error": f"{type(exc).__name__}: {exc}".splitlines()[0][:300]}
    finally:
        signal.alarm(0)
    if not args.no_sindy:
        started = time.perf_counter()
        try:
            result = sindy.run(case)
            row["sindy"] = {**sindy.score(result, case.truth),
                            "top": {t: r["terms"][0] if r["terms"] else None for t, r in result.items()}}
        except Exception as exc:
            row["sindy"] = {"error": f"{type(exc).__name__}: {exc}".splitlines()[0][:300]}
        row["sindy_s"] = time.perf_counter() - started
    return row


def _rate(rows, method, key, where=lambda r: True) -> str:
    """``k/n (p %)`` of rows whose figure ``key`` applies; errors count as failures."""
    picked = [r for r in rows if where(r) and (r[method].get(key) is not None or "error" in r[method])]
    if not picked:
        return "-"
    hits = sum(bool(r[method].get(key)) for r in picked)
    return f"{hits}/{len(picked)} ({100 * hits / len(picked):.0f} %)"


def _inverse_rate(rows, method, key, where=lambda r: True) -> str:
    """Like :func:`_rate` for figures where True is the failure; errors count as not failing."""
    picked = [r for r in rows if where(r) and r[method].get(key) is not None]
    if not picked:
        return "-"
    hits = sum(bool(r[method][key]) for r in picked)
    return f"{hits}/{len(picked)} ({100 * hits / len(picked):.0f} %)"


def _is(kind):
    return lambda r: r["truth"]["kind"] == kind


def _low(kind):
    return lambda r: r["truth"]["kind"] == kind and r["noise"] <= LOW_NOISE


def _at(kind, noise):
    return lambda r: r["truth"]["kind"] == kind and r["noise"] == noise


def table(rows: list[dict], group: str, labels: list) -> str:
    """Our figures, one line per group value."""
    head = ("| " + group + " | cases | top-1 <= 1 % noise | top-1 at 5 % | top-1 all | null: no gap | "
            "null theta within 3 % (<= 1 % noise) | out-of-catalogue: confident wrong name | wrong names (all cases) | "
            "re-fitted start no worse (held-out free run) | diverged beside a verdict (any model / its own) | errors | "
            "s per case |")
    lines = [head, "|" + "---|" * 13]
    for label in labels + ["all"]:
        part = [r for r in rows if label == "all" or r[group] == label]
        if not part:
            continue
        seconds = [r["diagnose_s"] for r in part if "diagnose_s" in r]
        lines.append(
            f"| {label} | {len(part)} | {_rate(part, 'ours', 'top1', _low('catalogued'))} | "
            f"{_rate(part, 'ours', 'top1', _at('catalogued', 0.05))} | {_rate(part, 'ours', 'top1', _is('catalogued'))} | "
            f"{_rate(part, 'ours', 'no_gap', _is('null'))} | {_rate(part, 'ours', 'theta_ok', _low('null'))} | "
            f"{_inverse_rate(part, 'ours', 'confident_wrong')} | {_inverse_rate(part, 'ours', 'wrong_name')} | "
            f"{_rate(part, 'ours', 'retuned_no_worse')} | "
            f"{_inverse_rate(part, 'ours', 'diverged_beside_verdict')} / "
            f"{_inverse_rate(part, 'ours', 'own_run_diverged')} | "
            f"{sum('error' in r['ours'] for r in part)} | "
            f"{(sum(seconds) / len(seconds)) if seconds else math.nan:.2f} |")
    return "\n".join(lines)


def sindy_table(rows: list[dict], group: str, labels: list) -> str:
    """The baseline's figures beside ours (strict top-1 and null rule), one line per group value."""
    lines = [f"| {group} | top-1 <= 1 % noise (ours / PySINDy) | top-1 at 5 % (ours / PySINDy) | "
             "top-1 all (ours / PySINDy) | null: no gap (ours / PySINDy) | PySINDy s per case |", "|" + "---|" * 6]
    for label in labels + ["all"]:
        part = [r for r in rows if (label == "all" or r[group] == label) and "sindy" in r]
        if not part:
            continue
        both = lambda key, where: f"{_rate(part, 'ours', key, where)} / {_rate(part, 'sindy', key, where)}"
        seconds = [r["sindy_s"] for r in part]
        lines.append(f"| {label} | {both('top1', _low('catalogued'))} | {both('top1', _at('catalogued', 0.05))} | "
                     f"{both('top1', _is('catalogued'))} | {both('no_gap', _is('null'))} | "
                     f"{sum(seconds) / len(seconds):.2f} |")
    return "\n".join(lines)


def _identifiable(noise=None):
    return lambda r: (r.get("oracle") or {}).get("identifiable") is True and (noise is None or r["noise"] == noise)


def acceptance_table(rows: list[dict], group: str, labels: list) -> str:
    """Issue 54's acceptance figures, one line per group value: on cases whose record pins the true
    law (:mod:`msam_torch.zoo.oracle`), the share named right; on all cases, the share of confident
    wrong names; nulls' "no significant gap"; cases printing "no significant gap" beside their own
    evidence of one; and on cases whose diagnosis names an effect, ``msam run`` reading the same law
    or stating why it differs (:mod:`msam_torch.zoo.one_answer`). PySINDy's beside ours."""
    lines = [(f"| {group} | cases | identifiable (of catalogued) | named right, identifiable (ours / PySINDy) | "
              "confident wrong names, all cases (ours / PySINDy) | out of catalogue answered right | "
              "nulls: no gap (ours / PySINDy) | 'no gap' beside evidence of a gap | "
              "msam run: same law or states why (same law) |"), "|" + "---|" * 9]
    for label in labels + ["all"]:
        part = [r for r in rows if label == "all" or r[group] == label]
        if not part:
            continue
        both = lambda rate, key, where, part=part: f"{rate(part, 'ours', key, where)} / " + (
            rate(part, "sindy", key, where) if all("sindy" in r for r in part) else "-")
        catalogued = [r for r in part if r["truth"]["kind"] == "catalogued"]
        named = [r for r in part if isinstance(r["ours"].get("one_answer"), dict)]
        answered = sum(bool(r["ours"]["one_answer"].get("agrees_or_states")) for r in named)
        same = sum(bool(r["ours"]["one_answer"].get("same")) for r in named)
        lines.append(
            f"| {label} | {len(part)} | {sum(_identifiable()(r) for r in catalogued)}/{len(catalogued)} | "
            f"{both(_rate, 'top1', _identifiable())} | {both(_inverse_rate, 'wrong_name', lambda r: True)} | "
            f"{_rate(part, 'ours', 'answered_right', _is('out_of_catalogue'))} | {both(_rate, 'no_gap', _is('null'))} | "
            f"{sum(bool(r['ours'].get('no_gap_beside_evidence')) for r in part)} | "
            f"{answered}/{len(named)} ({same}) |")
    return "\n".join(lines)


def effect_table(rows: list[dict]) -> str:
    """Strict top-1 (catalogued) or confident wrong names (out of catalogue) per withheld effect."""
    names = sorted({r["truth"]["name"] or "(null)" for r in rows})
    lines = ["| withheld effect | cases | ours: top-1 / no gap / confident wrong | PySINDy: top-1 / no gap |", "|---|---|---|---|"]
    for name in names:
        part = [r for r in rows if (r["truth"]["name"] or "(null)") == name]
        key = {"catalogued": "top1", "null": "no_gap", "out_of_catalogue": "confident_wrong"}[part[0]["truth"]["kind"]]
        ours = (_inverse_rate if key == "confident_wrong" else _rate)(part, "ours", key)
        theirs = _rate(part, "sindy", key) if key != "confident_wrong" and all("sindy" in r for r in part) else "-"
        lines.append(f"| {name} | {len(part)} | {ours} | {theirs} |")
    return "\n".join(lines)


def _worker() -> None:
    """A process that diagnoses cases: one torch thread, freed memory kept, the per-case alarm."""
    keep_freed_memory()
    torch.set_num_threads(1)
    signal.signal(signal.SIGALRM, _alarm)


def _diagnosed(seeds: list[int], args):
    """The rows of ``seeds`` as they finish: in this process (one worker) or in ``args.workers``
    processes side by side."""
    if args.workers <= 1 or len(seeds) <= 1:
        yield from (run_case(seed, args) for seed in seeds)
        return
    with ProcessPoolExecutor(min(args.workers, len(seeds)), mp_context=get_context("spawn"), initializer=_worker) as pool:
        yield from (future.result() for future in as_completed([pool.submit(run_case, seed, args) for seed in seeds]))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=300)
    parser.add_argument("--seed-start", type=int, default=1000)
    parser.add_argument("--noise", type=float, nargs="*", default=None, help="noise levels cycled over the seeds")
    parser.add_argument("--domains", nargs="*", choices=sorted(DOMAINS), default=None)
    parser.add_argument("--timeout", type=int, default=120, help="seconds per diagnosis")
    parser.add_argument("--no-sindy", action="store_true")
    parser.add_argument("--out", type=Path, default=None, help="JSON lines, one per case (resumed if present)")
    parser.add_argument("--max-new", type=int, default=None,
                        help="diagnose at most this many cases not in --out, then tabulate what is done")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                        help="processes diagnosing cases side by side, one torch thread each (default: the CPUs)")
    args = parser.parse_args(argv)
    _worker()
    done = {}
    if args.out is not None and args.out.exists():
        done = {row["seed"]: row for row in map(json.loads, args.out.read_text().splitlines())}
    seeds = range(args.seed_start, args.seed_start + args.cases)
    budget = len(seeds) if args.max_new is None else args.max_new
    todo = [seed for seed in seeds if seed not in done][:max(0, budget)]
    rows, started = [done[seed] for seed in seeds if seed in done], time.perf_counter()
    for row in _diagnosed(todo, args):
        if args.out is not None:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            with args.out.open("a") as stream:
                stream.write(json.dumps(_finite(row)) + "\n")
        rows.append(row)
        ours = row["ours"]
        outcome = ours.get("error") or ours["verdict"]
        print(f"[{len(rows)}/{args.cases}] seed {row['seed']} {row['domain']}/{row['system']} noise {row['noise']:g} "
              f"truth {row['truth']['name'] or 'none'} -> {outcome} "
              f"({row.get('diagnose_s', math.nan):.1f} s; {time.perf_counter() - started:.0f} s total)",
              file=sys.stderr, flush=True)
    rows.sort(key=lambda r: r["seed"])
    domains = sorted({r["domain"] for r in rows})
    noises = sorted({r["noise"] for r in rows})
    partial = "" if len(rows) == args.cases else f" of {args.cases} (partial: the other seeds not yet diagnosed)"
    print(f"# Zoo: {len(rows)} cases{partial}, seeds {args.seed_start}-{args.seed_start + args.cases - 1}\n")
    print("## Acceptance figures by domain\n\n" + acceptance_table(rows, "domain", domains) + "\n")
    print("## Acceptance figures by noise level\n\n" + acceptance_table(rows, "noise", noises) + "\n")
    print("## msam diagnose by domain\n\n" + table(rows, "domain", domains) + "\n")
    print("## msam diagnose by noise level\n\n" + table(rows, "noise", noises) + "\n")
    if not args.no_sindy:
        print("## Beside PySINDy (same cases) by domain\n\n" + sindy_table(rows, "domain", domains) + "\n")
        print("## Beside PySINDy by noise level\n\n" + sindy_table(rows, "noise", noises) + "\n")
    print("## By withheld effect\n\n" + effect_table(rows) + "\n")
    print("## Outcome classes (ours)\n\n" + score.outcome_table(rows) + "\n")
    total = sum(r.get("generate_s", 0) + r.get("diagnose_s", 0) + r.get("checks_s", 0) + r.get("sindy_s", 0) for r in rows)
    print(f"time per case: {total / max(1, len(rows)):.2f} s (generate + diagnose + oracle and msam run + PySINDy); "
          f"wall {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
