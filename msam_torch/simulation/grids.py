"""Step grids kept for reuse: a fixed-step run of a row (its parameters and start) on a record is
a function of that row alone, so a row integrated once (by a line search, an evaluation, a
Levenberg-Marquardt trial) is not integrated again when the next call needs it (the plain run
under the forward-mode tangents of :mod:`.sensitivities`, a free run of the fitted rows). Rows
match by their exact bits; a row not kept is integrated as before, so what is read is what a new
run would give."""
from __future__ import annotations

import torch

KEEP = 3  # batches kept: the latest calls' grids (a line search's, a step's, an evaluation's)


class Grids:
    """The grids (U, steps + 1, S) of the latest :data:`KEEP` batches of rows, each under the
    context it was run in (model, record, step, tableau, limits: :meth:`context`)."""

    def __init__(self):
        self._batches: list[tuple[tuple, dict[bytes, int], torch.Tensor]] = []

    @staticmethod
    def context(model, record, tableau, h, steps: int, limits, span) -> tuple:
        """What a run depends on besides its rows: compared by identity (the model, the record's
        tensors, kept alive with the batch) and value (step, tableau, limits, span)."""
        plain = lambda v: None if v is None else v.detach()
        number = lambda v: None if v is None else tuple(plain(v).flatten().tolist())
        return (model, plain(record.t), plain(record.external), plain(record.pieces), record.hold,
                number(record.held), tableau, float(h), steps, number(limits), number(span))

    def take(self, context: tuple, keys: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Which rows (``keys`` (U, D)) are kept (U,) and their grids (hits, steps + 1, S), each
        from the latest batch that holds it."""
        rows = [k.tobytes() for k in keys.cpu().numpy()]
        found: list = [None] * len(rows)
        for kept, index, grid in reversed(self._batches):
            if _same(kept, context):
                found = [f if f is not None else (grid, index[r]) if r in index else None for f, r in zip(found, rows)]
        hit = torch.tensor([f is not None for f in found], dtype=torch.bool, device=keys.device)
        if not bool(hit.any()):
            return hit, None
        return hit, torch.stack([grid[k] for grid, k in (f for f in found if f is not None)])

    def keep(self, context: tuple, keys: torch.Tensor, grid: torch.Tensor) -> None:
        """Keep the grids of rows ``keys`` (U, D); rows with a value that is not a number are not kept."""
        finite = torch.isfinite(keys).all(-1)
        if not bool(finite.any()):
            return
        rows = [k.tobytes() for k in keys[finite].cpu().numpy()]
        self._batches = self._batches[-(KEEP - 1):] + [(context, dict(zip(rows, range(len(rows)))), grid[finite])]


def _same(a: tuple, b: tuple) -> bool:
    """Contexts equal: tensors by identity of their data, everything else by value."""
    def equal(x, y):
        if torch.is_tensor(x) or torch.is_tensor(y):
            return torch.is_tensor(x) and torch.is_tensor(y) and x.data_ptr() == y.data_ptr() \
                and x.shape == y.shape and x.stride() == y.stride() and x.dtype == y.dtype
        return x is y if hasattr(x, "equations") else x == y
    return len(a) == len(b) and all(equal(x, y) for x, y in zip(a, b))
