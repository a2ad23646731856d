"""TensorBoard tracker: a trainer callback that logs every step, the run's hparams and a layout.

Per candidate, named by its adjustments (``abs_x_dot-abs_x``: the adjustment function of each
adjustable component, characters TensorBoard does not take replaced by ``_``): ``fitness``,
``sum_abs_error``, ``rho``, ``gamma_<i>``, ``mu``, ``cond_scaled`` and ``cond_unscaled``
(``cond(Phi^T Phi)`` with and without dM scaling; attaching the tracker switches on the trainer's
``diagnostics``). Tags are ``<target>/<stage>/<measure>/<candidate>`` (``winner`` in the
refinement). A custom-scalars layout overlays the candidates of each measure in one chart;
:meth:`TensorBoardTracker.log_run` writes the config's options as hparams with the final
measures of every equation (Eq. 19) as metrics. Only trial 0 is logged; with more than
``max_candidates`` candidates only the best ``max_candidates`` by current fitness are.
:meth:`TensorBoardTracker.log_diagnosis` logs a gap report (``msam diagnose``): its summary, its
numbers and its figures as images.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import torch

from msam_torch.run.result import write_atomic

STAGES = ("round_robin", "refinement")


def tag_name(text: str) -> str:
    """``abs(x_dot)`` -> ``abs_x_dot``: a name TensorBoard keeps as it is."""
    return re.sub(r"[^-\w.]+", "_", text).strip("_")


def flatten(config: dict, prefix: str = "") -> dict:
    """Scalar leaves of a nested config as ``section.key`` -> value (lists as text)."""
    out = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        elif isinstance(value, (bool, int, float, str)):
            out[name] = value
        elif value is not None:
            out[name] = str(value)
    return out


class TensorBoardTracker:
    def __init__(self, log_dir: str | Path, max_candidates: int = 64):
        self.log_dir = Path(log_dir)
        self.max_candidates = max_candidates
        self._writer = None
        self._measures: dict[str, set[str]] = {}  # prefix -> measures logged (the layout)

    @property
    def writer(self):
        """The SummaryWriter, created on first use so a run that fails early writes nothing."""
        if self._writer is None:
            from torch.utils.tensorboard import SummaryWriter

            self._writer = SummaryWriter(str(self.log_dir))
        return self._writer

    def save_config(self, text: str) -> None:
        """The resolved config beside the event files."""
        write_atomic(self.log_dir / "config.yaml", text)

    def attach(self, trainer, prefix: str, labels) -> None:
        """Log ``trainer``'s steps under ``prefix``; ``labels(choice)`` lists a candidate's adjustments."""
        trainer.diagnostics = True  # the condition numbers are logged
        name = lambda choice: "-".join(tag_name(text) for text in labels(choice)) or "start"
        trainer.add_callback("round_robin_step", lambda t, **p: self._log(prefix, "round_robin", p, name))
        trainer.add_callback("refinement_step", lambda t, **p: self._log(prefix, "refinement", p, name))
        trainer.add_callback("round_robin_end", lambda t, choices, **p: self.writer.add_text(
            f"{prefix}/candidates", "  \n".join(f"{name(c)}: {', '.join(labels(c))}" for c in choices)))

    def _log(self, prefix: str, stage: str, payload: dict, name) -> None:
        result, evaluation, step = payload["result"], payload["evaluation"], payload["iteration"] + 1
        values = {
            "fitness": evaluation.fitness[0], "sum_abs_error": evaluation.sum_abs_error[0], "rho": evaluation.rho[0],
            "mu": result.mu[0], "cond_scaled": result.cond_scaled[0], "cond_unscaled": result.cond_unscaled[0],
        }
        gamma = result.state.gamma[0]
        count = gamma.shape[0]
        shown = torch.arange(count)
        if count > self.max_candidates:
            shown = torch.topk(torch.nan_to_num(values["fitness"], neginf=-1e300), self.max_candidates).indices
        rows = {k: v.detach().cpu().tolist() for k, v in values.items()}
        rows.update({f"gamma_{i}": row for i, row in enumerate(gamma.detach().cpu().T.tolist())})
        self._measures.setdefault(prefix, set()).update(rows)
        for c in shown.tolist():
            label = name(payload["choices"][c]) if stage == "round_robin" else "winner"
            for measure, row in rows.items():
                self.writer.add_scalar(f"{prefix}/{stage}/{measure}/{label}", row[c], step)

    def log_run(self, config: dict, result) -> None:
        """The run as one row of the hparams table: the config's options (``adaptation.*``,
        ``data.*``) and the final ``fitness``, ``sum_abs_error``, ``rho`` of each equation."""
        from torch.utils.tensorboard.summary import hparams

        options = {k: v for k, v in flatten(config).items() if k.startswith(("adaptation.", "data."))}
        metrics = {f"{eq.target}/adapted/{k}": float(v) for eq in result.equations for k, v in eq.adapted.items()}
        for summary in hparams(options, metrics):
            self.writer.file_writer.add_summary(summary)
        for tag, value in metrics.items():
            self.writer.add_scalar(tag, value)

    def log_diagnosis(self, report, figures=()) -> None:
        """A gap report: its summary as text (``diagnosis/summary``); per equation the fitted
        ``exponent``, the held-out ``improvement`` and the bootstrap ``win_frequency``
        (``diagnosis/<target>/...``); per record the free-run NRMSE of each model
        (``diagnosis/free_run_nrmse/<record>/<model>``); the report's figures
        (:class:`~msam_torch.diagnosis.report.figures.Figure`) as images (``diagnosis/<figure>``), their
        PNG bytes as they are (not decoded and encoded again)."""
        from tensorboard.compat.proto.summary_pb2 import Summary

        self.writer.add_text("diagnosis/summary", "\n".join("    " + line for line in str(report).splitlines()))
        for g in report.equations:
            values = {"exponent": g.exponent, "improvement": g.improvement.get("relative"),
                      "win_frequency": g.confidence.get("win_frequency")}
            for measure, value in values.items():
                if value is not None and math.isfinite(value):
                    self.writer.add_scalar(f"diagnosis/{tag_name(g.target)}/{measure}", value)
        for record, entry in report.measures.get("free_run", {}).items():
            for model, value in entry["nrmse"].items():
                if value is not None:
                    self.writer.add_scalar(f"diagnosis/free_run_nrmse/{record}/{model}", value)
        for figure in figures:
            width, height = (int.from_bytes(figure.png[k:k + 4], "big") for k in (16, 20))  # the PNG's IHDR chunk
            image = Summary.Image(height=height, width=width, colorspace=4, encoded_image_string=figure.png)  # RGBA
            tag = f"diagnosis/{tag_name(figure.name.removesuffix('.png'))}"
            self.writer.file_writer.add_summary(Summary(value=[Summary.Value(tag=tag, image=image)]))

    def layout(self) -> dict:
        """Custom-scalars layout: per equation, one chart per stage and measure overlaying every candidate."""
        return {prefix: {f"{stage} {measure}": ["Multiline", [f"^{re.escape(prefix)}/{stage}/{measure}/"]]
                         for stage in STAGES for measure in sorted(measures)}
                for prefix, measures in self._measures.items()}

    def close(self) -> None:
        if self._writer is not None:
            if self._measures:
                self._writer.add_custom_scalars(self.layout())
            self._writer.flush()
            self._writer.close()
