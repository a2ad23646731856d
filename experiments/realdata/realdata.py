"""MSAM on the real benchmark records carried in ``msam_torch/data/datasets``: what ``msam run`` finds.

    python -m experiments.realdata.realdata [silverbox emps cascaded_tanks us_is]

For each configs/<case>.yaml: the adapted equation, its exponents, the theta-retuned starting model
against the adapted one (one-step error of the modelled derivative on training and validation, the
relative force error for EMPS, free-run RMSE where the record allows it) and the run time.
The theta-retuned starting model is the unadjusted model with every theta fitted by linear least
squares on the training record (the same estimated signals the adaptation saw).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.loading import load_datasets
from msam_torch.diagnosis.compare.refit import (
    errors,
    force_error,
    named_laws,
    one_step,
    retuned_at,
    retuned_start,
    rival,
)
from msam_torch.engine.allocator import keep_freed_memory
from msam_torch.engine.candidates import EquationData
from msam_torch.run.adapt import adapt
from msam_torch.simulation.free_run import free_run_models

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def run(case: str) -> None:
    path = CONFIGS / f"{case}.yaml"
    config = load_config(path)
    spec = to_spec(config.model)
    begin = time.perf_counter()
    result = adapt(path)
    elapsed = time.perf_counter() - begin
    print(f"== {case}  ({elapsed:.1f} s, {config.adaptation.evaluation} evaluation)")
    for eq in result.equations:
        print(f"  start:   {eq.start_equation}")
        print(f"  adapted: {eq.equation}")
        if len(eq.ranking) > 1:
            print(f"  winner {eq.ranking[0]['adjustments']}, runner-up {eq.ranking[1]['adjustments']} "
                  f"(fitness {eq.ranking[0]['fitness']:.4g} vs {eq.ranking[1]['fitness']:.4g})")
        else:  # a single candidate (every component restricted to one adjustment): nothing to rank
            print(f"  single candidate {eq.ranking[0]['adjustments']} (fitness {eq.ranking[0]['fitness']:.4g})")
        equation = spec.equations[[e.target for e in spec.equations].index(eq.target)]
        named = [name for _, name, _ in named_laws(equation, eq, spec.theta(equation))]
        other = rival(equation, eq, spec.theta(equation))
        if named and other is not None:
            rank, row = other
            print(f"  named: {', '.join(named)}; best candidate naming other laws: rank {rank + 1} "
                  f"{row['adjustments']} (fitness {row['fitness']:.4g}; the winner's is "
                  f"{eq.ranking[0]['fitness'] / row['fitness']:.2f}x)")
    if config.adaptation.evaluation == "simulation":
        for group in result.data["simulation"]:
            print(f"  initial states {group['initial']}")
            for record, rows in group["free_run_rmse"].items():
                print(f"  free-run RMSE {record}: " + ", ".join(f"{k} {v[0]:.4f}" for k, v in rows.items()))
        return
    train, validation = load_datasets(config.data, spec, path.parent)
    models = {"retuned start": [], "adapted": []}
    for equation, eq in zip(spec.equations, result.equations):
        data = EquationData.build(equation, train.signals)
        models["retuned start"].append(retuned_start(equation, data))
        models["adapted"].append(eq)
        for name, dataset in (("train", train), ("validation", validation)):
            if dataset is None:
                continue
            y = dataset.signals[equation.target]
            row = {label: errors(y, one_step(equation, entries[-1], dataset.signals)) for label, entries in models.items()}
            print(f"  one-step {equation.target} {name}: " + ", ".join(
                f"{label} sum|eps| {v['sum_abs']:.4g} rmse {v['rmse']:.4g} rel {100 * v['rel']:.2f} %" for label, v in row.items()))
            if "tau" in spec.inputs:
                print(f"  relative force error {name}: " + ", ".join(
                    f"{label} {100 * force_error(equation, entries[-1], dataset.signals, 'tau'):.2f} %" for label, entries in models.items()))
        if "tau" in spec.inputs:  # EMPS: the components as forces, M = 1 / theta_tau
            texts = [c.term.text for c in equation.components]
            mass = 1.0 / eq.theta[texts.index("tau")]
            speed = float(train.signals["q_dot"].abs().median())
            print(f"  M = {mass:.2f} kg; friction and offset as forces (at the median speed {speed:.4f} m/s):")
            for text, a, g, th in zip(texts, eq.adjustments, eq.exponents, eq.theta):
                if text == "tau":
                    continue
                law = text if a is None else f"{text}|{a[4:-1]}|^{g:.3f}"
                at_median = -th * mass * (speed ** (1 + g) if text == "q_dot" and a == "abs(q_dot)" else
                                          speed if text == "q_dot" else 1.0)
                print(f"    {law}: coefficient {-th * mass:.4g}, force at median speed {at_median:.4g} N")
            for i, name, exponent in named_laws(equation, eq, spec.theta(equation)):
                named = retuned_at(equation, eq, train.signals, i, exponent)
                m = 1.0 / named.theta[texts.index("tau")]
                held = "" if validation is None else \
                    f", validation {100 * force_error(equation, named, validation.signals, 'tau'):.2f} %"
                print(f"  {name}: at its catalogue exponent {exponent:g}, theta re-estimated on the training record: "
                      f"magnitude {-named.theta[i] * m:.4g} N, M = {m:.2f} kg, relative force error train "
                      f"{100 * force_error(equation, named, train.signals, 'tau'):.2f} %{held}")
    if config.adaptation.simulation.output:
        runs = free_run_models(config, spec, models, path.parent, records=("validation",), steps=3)
        for record, rows in runs["free_run_rmse"].items():
            print(f"  free-run RMSE {record} ({', '.join(runs['outputs'])}): " + ", ".join(
                f"{k} {v[0]:.5g}" for k, v in rows.items()))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="*", default=["silverbox", "emps", "cascaded_tanks", "us_is"],
                        help="configs/<case>.yaml to run (default: all four)")
    keep_freed_memory()
    torch.set_num_threads(2)
    for case in parser.parse_args().cases:
        run(case)
