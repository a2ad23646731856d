"""Figure 5: cond(Phi^T Phi) with and without dM scaling, per parametric error level, for the
correct candidate and over all candidates of the round robin (docs/design.md 2.10: report what is
measured). Every trial stores log10 cond per iteration and candidate.

    python -m experiments.paper.figure5 [experiments/paper/figure5.yaml] [--out DIR] [--max-trials K]
"""
from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

import pandas as pd
import torch

from experiments.common import (
    arguments,
    dump_config,
    load_experiment,
    main_guard,
    markdown_table,
    model_config,
    model_path,
    protocol_notes,
    run_protocol,
    save_figure,
    tensorboard_scalars,
    write_csv,
    write_text,
)
from msam_torch.data.loading import load_datasets
from msam_torch.run.plan import prepare
from msam_torch.run.trials import fit_equation, trial_parameters


def log10(values: torch.Tensor) -> list:
    return torch.log10(values).tolist()


def compute_factory(experiment, config_path):
    def compute(config, trials):
        plan = prepare(config)
        spec = plan.spec
        train, _ = load_datasets(config.data, spec, model_path(experiment, config_path).parent, estimator=plan.derivatives)
        parameters = [trial_parameters(spec.parameters, t, experiment.seed) for t in trials]
        records = [{"level": t.level, "index": t.index, "parameters": p, "equations": []} for t, p in zip(trials, parameters)]
        for equation in spec.equations:
            groups = []

            def on_trainer(trainer, eq):
                groups.append({})
                trainer.diagnostics = True  # the condition numbers are what this figure records
                trainer.add_callback("round_robin_step", lambda t, iteration, offset, result, **p: groups[-1].setdefault(
                    iteration, {}).update({offset: (result.cond_scaled, result.cond_unscaled)}))

            fit, _, _ = fit_equation(plan, equation, train.signals, parameters, on_trainer=on_trainer,
                                     max_elements=experiment.max_elements)
            texts = [f.text for f in equation.adjustments]
            truth = experiment.equations[equation.target].truth
            correct = [k for k, c in enumerate(fit.choices.tolist()) if [texts[i] for i in c] == truth]
            row = 0
            for group in groups:
                scaled = torch.stack([torch.cat([group[i][o][0] for o in sorted(group[i])], 1) for i in sorted(group)], 1)
                unscaled = torch.stack([torch.cat([group[i][o][1] for o in sorted(group[i])], 1) for i in sorted(group)], 1)
                for k in range(scaled.shape[0]):  # (T, iterations, C)
                    records[row]["equations"].append({"target": equation.target, "correct_candidate": correct[0],
                                                      "log10_cond_scaled": log10(scaled[k]),
                                                      "log10_cond_unscaled": log10(unscaled[k])})
                    row += 1
        return records
    return compute


def stats(values: list[float]) -> tuple[float, float, int]:
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return math.nan, math.nan, 0
    return statistics.fmean(finite), (statistics.stdev(finite) if len(finite) > 1 else 0.0), len(values) - len(finite)


def main() -> int:
    args = arguments("experiments/paper/figure5.yaml", "experiments/results/figure5", __doc__)
    config_path, out = Path(args.config), Path(args.out)
    experiment = load_experiment(config_path)
    started = time.perf_counter()
    results = run_protocol(experiment, config_path, out, compute_factory(experiment, config_path), args.max_trials)
    if results is None:
        print("stopped early; run again to finish")
        return 0
    records = results["paper"]
    rows = []
    for level in experiment.levels:
        eqs = [r["equations"][0] for r in records if r["level"] == level]
        for subset in ("correct candidate", "all candidates"):
            row = {"level": level, "subset": subset}
            for kind in ("scaled", "unscaled"):
                values = [v for e in eqs for it in e[f"log10_cond_{kind}"]
                          for c, v in enumerate(it) if subset == "all candidates" or c == e["correct_candidate"]]
                row[f"{kind}_mean"], row[f"{kind}_std"], row[f"{kind}_singular"] = stats(values)
            rows.append(row)
    frame = pd.DataFrame(rows)
    write_csv(out, "figure5.csv", frame)
    header = ["ΔΘ", "candidates", "log10 cond, dM-scaled (mean ± std)", "log10 cond, unscaled (mean ± std)", "singular (scaled/unscaled)"]
    table = [[f"{round(100 * r['level'])}%", r["subset"], f"{r['scaled_mean']:.2f} ± {r['scaled_std']:.2f}",
              f"{r['unscaled_mean']:.2f} ± {r['unscaled_std']:.2f}", f"{r['scaled_singular']}/{r['unscaled_singular']}"] for r in rows]
    config = model_config(experiment, config_path, "paper")
    text = (f"# {experiment.title}\n\n{experiment.trials} trials x {config.adaptation.round_robin_steps} round-robin "
            f"iterations per level; log10 of cond(Phi^T Phi) = lambda_max / lambda_min. The paper's claim: "
            f"{experiment.paper.get('claim', '')}. Ours, as measured:\n\n{markdown_table(header, table)}\n\n"
            f"## Protocol\n\n{protocol_notes(config, experiment)}\n")
    write_text(out, "figure5.md", text)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.5), sharey=True)
    for ax, subset in zip(axes, ("correct candidate", "all candidates")):
        part = frame[frame.subset == subset]
        x = torch.arange(len(part)).tolist()
        ax.bar([i - 0.2 for i in x], part.scaled_mean, 0.4, yerr=part.scaled_std, label="dM-scaled")
        ax.bar([i + 0.2 for i in x], part.unscaled_mean, 0.4, yerr=part.unscaled_std, label="unscaled")
        ax.set_xticks(x, [f"{round(100 * l)}%" for l in part.level])
        ax.set(title=subset, xlabel="ΔΘ", ylabel="log10 cond(Φᵀ Φ)")
        ax.legend(fontsize=7)
    save_figure(fig, out / "figure5.png")
    scalars = {f"{s}/{k}": [(round(100 * r["level"]), r[f"{k}_mean"]) for r in rows if r["subset"] == s]
               for s in ("correct candidate", "all candidates") for k in ("scaled", "unscaled")}
    tensorboard_scalars(out, "paper", {k.replace(" ", "_"): v for k, v in scalars.items()}, dump_config(config))
    print(text)
    print(f"wrote {out}/figure5.md, figure5.csv, figure5.png, tensorboard/ in {time.perf_counter() - started:.2f} s")
    return 0


if __name__ == "__main__":
    main_guard(main)
