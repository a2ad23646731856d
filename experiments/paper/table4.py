"""Table 4: success of the round robin for the harmonic oscillator at 0-200 % parametric error,
for the paper's method and for the improved options, side by side with the paper's figures.

    python -m experiments.paper.table4 [experiments/paper/table4.yaml] [--out DIR] [--max-trials K]
"""
from __future__ import annotations

import time
from pathlib import Path

import pandas as pd

from experiments.common import (
    arguments,
    dump_config,
    load_experiment,
    main_guard,
    markdown_table,
    model_config,
    protocol_notes,
    run_protocol,
    save_figure,
    tensorboard_scalars,
    write_csv,
    write_text,
)


def success_rates(records: list[dict], levels: list[float]) -> list[float]:
    rates = []
    for level in levels:
        cell = [r for r in records if r["level"] == level]
        rates.append(sum(all(e["success"] for e in r["equations"]) for r in cell) / len(cell))
    return rates


def main() -> int:
    args = arguments("experiments/paper/table4.yaml", "experiments/results/table4", __doc__)
    config_path, out = Path(args.config), Path(args.out)
    experiment = load_experiment(config_path)
    started = time.perf_counter()
    results = run_protocol(experiment, config_path, out, max_trials=args.max_trials)
    if results is None:
        print("stopped early; run again to finish")
        return 0
    levels = experiment.levels
    rows = [{"variant": "paper (published)", **{f"{round(l * 100)}%": v for l, v in zip(levels, experiment.paper["success"])}}]
    for variant, records in results.items():
        rows.append({"variant": variant, **{f"{round(l * 100)}%": v for l, v in zip(levels, success_rates(records, levels))}})
    frame = pd.DataFrame(rows)
    write_csv(out, "table4.csv", frame)
    header = ["ΔΘ"] + [f"{round(l * 100)}%" for l in levels]
    table = [[experiment.labels.get(r["variant"], r["variant"])] + [f"{100 * r[h]:.0f}%" for h in header[1:]] for r in rows]
    notes = "\n\n".join(f"**{variant}**\n\n" + protocol_notes(model_config(experiment, config_path, variant), experiment)
                        for variant in experiment.variants)
    text = (f"# {experiment.title}\n\n{experiment.trials} trials per level; success = the correct adjustments "
            f"{experiment.equations['x_ddot'].truth if 'x_ddot' in experiment.equations else ''} chosen at the end of "
            f"the round robin.\n\n{markdown_table(header, table)}\n\n## Protocol\n\n{notes}\n")
    write_text(out, "table4.md", text)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    x = [100 * l for l in levels]
    for r in rows:
        ax.plot(x, [100 * r[h] for h in header[1:]], marker="o", label=experiment.labels.get(r["variant"], r["variant"]))
    ax.set(xlabel="parametric error ΔΘ (%)", ylabel="success rate (%)", title="Table 4", ylim=(-5, 105))
    ax.legend(fontsize=7)
    save_figure(fig, out / "table4.png")
    for variant, records in results.items():
        rates = success_rates(records, levels)
        tensorboard_scalars(out, variant, {"success_rate": [(round(100 * l), r) for l, r in zip(levels, rates)]},
                            dump_config(model_config(experiment, config_path, variant)))
    print(text)
    print(f"wrote {out}/table4.md, table4.csv, table4.png, tensorboard/ in {time.perf_counter() - started:.2f} s")
    return 0


if __name__ == "__main__":
    main_guard(main)
