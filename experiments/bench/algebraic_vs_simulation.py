"""Algebraic vs simulation-based evaluation on the controlled cases of Table 1.

    python -m experiments.bench.algebraic_vs_simulation [--cases harmonic vanderpol sode3]
        [--levels 0 0.25] [--trials 2] [--refinement 5] [--rules paper robust damped] [--out DIR] [--jobs 2]

Every case runs Algorithm 1 in both evaluation modes on the same exact simulated record, with
theta held at its nominal values, the config's round-robin steps (sode3: 15, the paper's count for
its first two equations) and ``--refinement`` refinement steps, under three step rules:

- ``paper``: the config's rule (dM-scaled step, Eq. 16-18, with mu by Eq. 20);
- ``robust``: a Gauss-Newton step in exponent units with a backtracking line search on the fitness.
- ``damped``: ``robust`` with Levenberg-Marquardt damping 0.1 (the measured preset's step for candidates
  judged by simulation, :data:`msam_torch.run.plan.SIMULATED`).

Simulation mode simulates the measured states (harmonic, van der Pol: x; third-order model: each
state with the other two read from the data, ``coupling: separate``) with the midpoint rule (fixed
step = sample time), and estimates the initial states by least squares (15 Levenberg-Marquardt
steps on the unadjusted starting model first); its sensitivities are exact (forward mode through
the solver). The last lines print the successes and time per evaluation and rule, and the cost
ratio of simulation to algebraic evaluation over all rows of the run, in wall time and in the
worker's CPU time (less moved by other load on a shared machine). Trials at a parametric-error
level draw the nominal parameters as docs/design.md 2.8 (``data.seed`` = trial); at level 0 every trial would be the same, so
one is run. Success: the winner's adjustment functions equal the target model's (Table 1). The time
is the wall time of all trials of a row (batched), data generation included.

Writes ``trials.csv`` (one row per trial) and ``summary.md`` atomically into ``--out``.
"""
from __future__ import annotations

import argparse
import multiprocessing
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pandas as pd
import torch

from experiments.common import ROOT, main_guard, markdown_table, set_threads, write_csv, write_text
from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.loading import load_datasets
from msam_torch.engine.candidates import EquationData
from msam_torch.run.adapt import nominal_parameters
from msam_torch.run.adapt_simulated import prepare_group
from msam_torch.run.plan import make_trainer, prepare
from msam_torch.simulation.ode import groups

CONFIGS = ROOT / "configs"
# The target model's adjustment per adjustable component (None: any function, its exponent ~0).
TARGETS = {
    "harmonic": [["abs(x_dot)", "abs(x)"]],
    "vanderpol": [["abs(x)", None, None]],
    "sode3": [["x3", "x3", "x3"], ["x2", "x1", "x3"], ["x2", "x1", "x3"]],
}
SIMULATION = {
    "harmonic": ["adaptation.simulation.output=[x]"],
    "vanderpol": ["adaptation.simulation.output=[x]"],
    "sode3": ["adaptation.simulation.output=[x1, x2, x3]", "adaptation.simulation.coupling=separate"],
}
CASE_OVERRIDES = {"sode3": ["adaptation.round_robin_steps=15"]}
RULES = {"paper": [], "robust": ["adaptation.scaling=gauss_newton", "adaptation.step_size=line_search"],
         "damped": ["adaptation.scaling=gauss_newton", "adaptation.step_size=line_search", "adaptation.damping=0.1"]}


def parameter_sets(config, spec, trials: int) -> list[dict]:
    return [nominal_parameters(config.model_copy(update={"data": config.data.model_copy(update={"seed": seed})}), spec)
            for seed in range(trials)]


def success(labels: list[list[list[str]]], targets: list[list]) -> list[bool]:
    """Per trial: every equation's winner matches its target."""
    return [all(all(t is None or t == w for t, w in zip(target, winner)) for target, winner in zip(targets, trial))
            for trial in labels]


def algebraic(config, spec, sets) -> tuple[list, list, list]:
    """Winners' labels, exponents and diverged candidates per trial and equation, trials batched."""
    train, _ = load_datasets(config.data, spec, CONFIGS)
    labels, exponents, diverged = [[] for _ in sets], [[] for _ in sets], [[] for _ in sets]
    for equation in spec.equations:
        data = EquationData.build(equation, train.signals, config.adaptation.normalize)
        data = data.expand_trials(len(sets))
        theta = torch.stack([spec.theta(equation, p) for p in sets])
        fit = make_trainer(prepare(config)).fit(data, theta[:, list(equation.adjustable)], theta[:, list(equation.fixed)])
        for k in range(len(sets)):
            labels[k].append([equation.adjustments[int(f)].text for f in fit.choices[fit.winner[k]]])
            exponents[k].append(fit.gamma[k].tolist())
            diverged[k].append(int(fit.diverged[k].sum()))
    return labels, exponents, diverged


def simulation(config, spec, sets) -> tuple[list, list, list]:
    """The same with simulation-based evaluation, one fit per group of equations."""
    plan = prepare(config)
    labels, exponents, diverged = [[] for _ in sets], [[] for _ in sets], [[] for _ in sets]
    for group in groups(spec, config.adaptation.simulation.coupling):
        prepared = prepare_group(plan, group, sets, CONFIGS)
        model = prepared.data.model
        trainer = make_trainer(plan)
        fit = trainer.fit(prepared.data, prepared.theta, prepared.theta_fixed, choices=model.choices())
        for k in range(len(sets)):
            chosen = [model.functions[int(f)].text for f in fit.choices[fit.winner[k]]]
            start = 0
            for eq in group:
                n = len(eq.adjustable)
                labels[k].append(chosen[start: start + n])
                exponents[k].append(fit.gamma[k, start: start + n].tolist())
                diverged[k].append(int(fit.diverged[k].sum()))
                start += n
    return labels, exponents, diverged


MODES = {"algebraic": (algebraic, lambda case: []),
         "simulation": (simulation, lambda case: ["adaptation.evaluation=simulation",
                                                  "adaptation.simulation.method=midpoint"] + SIMULATION[case])}


def run(case: str, level: float, mode: str, rule: str, trials: int, refinement: int) -> list[dict]:
    """One row of the comparison: every trial of (case, level, mode, step rule)."""
    compute, extra = MODES[mode]
    overrides = [f"data.parametric_error={level}", f"adaptation.refinement_steps={refinement}"] \
        + CASE_OVERRIDES.get(case, []) + RULES[rule] + extra(case)
    config = load_config(CONFIGS / f"{case}.yaml", overrides)
    spec = to_spec(config.model)
    sets = parameter_sets(config, spec, 1 if level == 0 else trials)
    begin, cpu = time.perf_counter(), time.process_time()
    labels, exponents, diverged = compute(config, spec, sets)
    seconds, cpu = time.perf_counter() - begin, time.process_time() - cpu
    ok = success(labels, TARGETS[case])
    return [{"case": case, "level": level, "evaluation": mode, "rule": rule, "trial": k, "success": ok[k],
             "winner": "; ".join(", ".join(w) for w in labels[k]),
             "exponents": "; ".join(", ".join(f"{g:.3f}" for g in e) for e in exponents[k]),
             "diverged": sum(diverged[k]), "seconds": seconds / len(sets), "cpu_seconds": cpu / len(sets)}
            for k in range(len(sets))]


def summary(rows: list[dict]) -> list[list]:
    """Per (case, level, evaluation, rule): successes, median exponents, diverged candidates, time."""
    frame = pd.DataFrame(rows)
    out = []
    for (case, level, mode, rule), part in frame.groupby(["case", "level", "evaluation", "rule"], sort=False):
        exponents = [[[float(g) for g in eq.split(", ")] for eq in e.split("; ")] for e in part["exponents"]]
        medians = "; ".join(", ".join(f"{statistics.median(e[q][i] for e in exponents):.3f}"
                                      for i in range(len(exponents[0][q]))) for q in range(len(exponents[0])))
        out.append([case, f"{level:.2f}", mode, rule, f"{int(part['success'].sum())}/{len(part)}", medians,
                    f"{part['diverged'].mean():.1f}", f"{part['seconds'].sum():.1f}"])
    return out


HEADER = ["case", "error", "evaluation", "step rule", "success", "median exponents (per equation)",
          "diverged candidates / trial", "time s"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(TARGETS), choices=list(TARGETS))
    parser.add_argument("--levels", type=float, nargs="+", default=[0.0, 0.25])
    parser.add_argument("--trials", type=int, default=2, help="trials per non-zero parametric-error level")
    parser.add_argument("--refinement", type=int, default=5)
    parser.add_argument("--rules", nargs="+", default=list(RULES), choices=list(RULES))
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    parser.add_argument("--out", default=str(ROOT / "experiments/results/algebraic_vs_simulation"))
    parser.add_argument("--jobs", type=int, default=2, help="rows computed in parallel, one torch thread each")
    args = parser.parse_args()
    rows, table = [], []
    print(markdown_table(HEADER, []), flush=True)
    jobs = [(case, level, mode, rule) for case in args.cases for level in args.levels for rule in args.rules
            for mode in args.modes]
    with ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("spawn"), initializer=set_threads,
                             initargs=(1,)) as pool:
        futures = [pool.submit(run, *job, args.trials, args.refinement) for job in jobs]
        for future in futures:  # in the order of the table
            rows += future.result()
            table.append(summary(future.result())[0])
            print(markdown_table(HEADER, table[-1:]).splitlines()[-1], flush=True)
    totals = pd.DataFrame(rows).groupby(["evaluation", "rule"])
    successes = totals["success"].agg(lambda v: f"{int(v.sum())}/{len(v)}").to_dict()
    seconds, cpu = totals["seconds"].sum().to_dict(), totals["cpu_seconds"].sum().to_dict()
    lines = [f"{mode}, {rule}: {successes[mode, rule]} trials succeed, {seconds[mode, rule]:.1f} s "
             f"({cpu[mode, rule]:.1f} s CPU)" for mode, rule in successes]
    if {"algebraic", "simulation"} <= set(args.modes):
        ratio = lambda v: sum(x for (mode, _), x in v.items() if mode == "simulation") \
            / max(sum(x for (mode, _), x in v.items() if mode == "algebraic"), 1e-9)
        lines.append(f"cost ratio simulation / algebraic (all rows of this run): {ratio(seconds):.1f}x wall, "
                     f"{ratio(cpu):.1f}x CPU time")
    print("\n" + "\n".join(f"- {line}" for line in lines))
    out = Path(args.out)
    write_csv(out, "trials.csv", pd.DataFrame(rows))
    notes = (f"Trials per non-zero error level: {args.trials} (level 0: 1); refinement steps: {args.refinement}; "
             f"{args.jobs} rows in parallel, one torch thread each. Step rules: paper = dM-scaled step with mu by Eq. 20; robust = "
             "Gauss-Newton step with a backtracking line search; damped = robust with damping 0.1. Time: all trials of the "
             "row, wall clock.")
    write_text(out, "summary.md", "# Algebraic vs simulation-based evaluation (Table 1 cases)\n\n"
               + markdown_table(HEADER, table) + "\n\n" + "\n".join(f"- {line}" for line in lines) + "\n\n" + notes + "\n")
    print(f"wrote {out / 'trials.csv'} and {out / 'summary.md'}")
    return 0


if __name__ == "__main__":
    main_guard(main)
