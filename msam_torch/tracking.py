"""TensorBoard tracker: a trainer callback that logs every step.

Per candidate (``c003`` = candidate 3 of the round robin; the ranking in ``result.json`` and the
``candidates`` text panel map indices to adjustments): ``fitness``, ``sum_abs_error``, ``rho``,
``gamma_<i>``, ``mu``, ``cond_scaled`` and ``cond_unscaled`` (``cond(Phi^T Phi)`` with and
without dM scaling; attaching the tracker switches on the trainer's ``diagnostics``). Tags are
``<target>/<stage>/<measure>/c<index>``. Only trial 0 is logged; with more than
``max_candidates`` candidates only the best ``max_candidates`` by current fitness are.
"""
from __future__ import annotations

from pathlib import Path

import torch

from .result import write_atomic


class TensorBoardTracker:
    def __init__(self, log_dir: str | Path, max_candidates: int = 64):
        self.log_dir = Path(log_dir)
        self.max_candidates = max_candidates
        self._writer = None

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
        """Log ``trainer``'s steps under ``prefix``; ``labels(choice)`` names a candidate."""
        trainer.diagnostics = True  # the condition numbers are logged
        trainer.add_callback("round_robin_step", lambda t, **p: self._log(prefix, "round_robin", p))
        trainer.add_callback("refinement_step", lambda t, **p: self._log(prefix, "refinement", p))
        trainer.add_callback("round_robin_end", lambda t, choices, **p: self.writer.add_text(
            f"{prefix}/candidates", "  \n".join(f"c{i:03d}: {labels(c)}" for i, c in enumerate(choices))))

    def _log(self, prefix: str, stage: str, payload: dict) -> None:
        result, evaluation, offset, step = payload["result"], payload["evaluation"], payload["offset"], payload["iteration"] + 1
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
        gammas = gamma.detach().cpu().tolist()
        for c in shown.tolist():
            name = f"c{offset + c:03d}" if stage == "round_robin" else "winner"
            for measure, row in rows.items():
                self.writer.add_scalar(f"{prefix}/{stage}/{measure}/{name}", row[c], step)
            for i, g in enumerate(gammas[c]):
                self.writer.add_scalar(f"{prefix}/{stage}/gamma_{i}/{name}", g, step)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.flush()
            self._writer.close()

