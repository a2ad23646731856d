"""Tables 2 and 3: trials of Algorithm 1 (round robin + refinement) at a few parametric error
levels; starting and final sum|eps| and rho, success rate and median final model per state
equation, beside the paper's figures. Used by ``table2.py`` and ``table3.py``."""
from __future__ import annotations

import time
from pathlib import Path

import pandas as pd

from experiments.common import (
    dump_config,
    load_experiment,
    markdown_table,
    model_config,
    protocol_notes,
    run_protocol,
    save_figure,
    summary_rows,
    tensorboard_scalars,
    write_csv,
    write_text,
)
from msam_torch.config.to_spec import to_spec

COLUMNS = ["start_sum_abs_error", "start_rho", "adapted_sum_abs_error", "adapted_rho"]


def run_tables(config_paths: list[Path], out: Path, name: str, max_trials: int | None = None) -> int:
    started = time.perf_counter()
    sections, frames, plots = [], [], []
    for config_path in config_paths:
        experiment = load_experiment(config_path)
        part_out = out / config_path.stem
        results = run_protocol(experiment, config_path, part_out, max_trials=max_trials)
        if results is None:
            print("stopped early; run again to finish")
            return 0
        for variant, records in results.items():
            config = model_config(experiment, config_path, variant)
            spec = to_spec(config.model)
            rows = []
            for position, equation in enumerate(spec.equations):
                ours = summary_rows(records, experiment.levels, equation, position)
                rows += ours
                plots.append((f"{config_path.stem} {equation.target}", ours))
            frame = pd.DataFrame(rows).assign(system=config_path.stem, variant=variant)
            frames.append(frame)
            paper = experiment.paper.get("rows", [])
            table = []
            for row in rows:
                match = [p for p in paper if p["level"] == row["level"] and p.get("target", row["target"]) == row["target"]]
                p = match[0] if match else {}
                pct = f"{round(row['level'] * 100)}%"
                success = "n/a" if row["success"] is None else f"{100 * row['success']:.0f}%"
                table.append([row["target"], pct, "ours"] + [row[c] for c in COLUMNS] + [success, row["median_adapted_model"]])
                if p:
                    paper_success = f"{100 * p['success']:.0f}%" if "success" in p else "100% (all cases, text)"
                    table.append([row["target"], pct, "paper"] + [p[c] for c in COLUMNS] + [paper_success, p["model"]])
            header = ["equation", "ΔΘ", "source", "start Σ|ε|", "start ρ", "final Σ|ε|", "final ρ", "success", "median final model"]
            sections.append(f"## {experiment.title} ({experiment.labels.get(variant, variant)})\n\n"
                            f"{experiment.trials} trials per level; success = the adjustments {dict((k, v.truth) for k, v in experiment.equations.items())} "
                            f"(null = any) chosen; ± is the standard deviation over trials.\n\n"
                            f"{markdown_table(header, table)}\n\n### Protocol\n\n{protocol_notes(config, experiment)}\n"
                            + "".join(f"- {t}: {s.round_robin_steps or config.adaptation.round_robin_steps} round-robin, "
                                      f"{s.refinement_steps if s.refinement_steps is not None else config.adaptation.refinement_steps} refinement steps\n"
                                      for t, s in experiment.equations.items()))
            scalars = {}
            for row in rows:
                for key in ("success",):
                    if row[key] is not None:
                        scalars.setdefault(f"{row['target']}/{key}", []).append((round(100 * row["level"]), row[key]))
            tensorboard_scalars(out, f"{config_path.stem}_{variant}", scalars, dump_config(config))
    write_csv(out, f"{name}.csv", pd.concat(frames))
    text = f"# {name.capitalize()}\n\n" + "\n".join(sections)
    write_text(out, f"{name}.md", text)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(plots), figsize=(4 * len(plots), 3.2), squeeze=False)
    for ax, (label, rows) in zip(axes[0], plots):
        levels = [100 * r["level"] for r in rows]
        for key in ("start_sum_abs_error", "adapted_sum_abs_error"):
            ax.plot(levels, [float(r[key].split(" ")[0]) for r in rows], marker="o", label=key.split("_")[0])
        ax.set(yscale="log", xlabel="ΔΘ (%)", ylabel="mean Σ|ε|", title=label)
        ax.legend(fontsize=7)
    save_figure(fig, out / f"{name}.png")
    print(text)
    print(f"wrote {out}/{name}.md, {name}.csv, {name}.png, tensorboard/ in {time.perf_counter() - started:.2f} s")
    return 0
