"""Axis labels and units of the report, from the config: ``model.quantities`` for the signals,
``data.time_unit`` for time (its frequencies and lags, and every derivative's unit)."""
from __future__ import annotations

from msam_torch.model.spec import split_derivative


class Units:
    """Axis labels from the config: a declared ``model.quantities`` unit (``x [m]``, a derivative
    ``x_dot [m per s]`` with ``data.time_unit: s``, else ``[m per time unit]``), else the declared
    quantity, else the data column it is read from, else a note that no unit is declared."""

    def __init__(self, config: dict):
        model, data = config.get("model", {}), config.get("data", {}) or {}
        self.quantities = model.get("quantities", {}) or {}
        self.columns = data.get("columns", {}) or {}
        self.time_unit = data.get("time_unit") or "time unit"  # singular: 'per s', 'per time unit'
        self.times = data.get("time_unit") or "time units"  # after a number: '0.04 s', '0.04 time units'
        source = f"column {data['time']}" if data.get("time") else "units of the record"
        self.time = f"time [{data['time_unit']}]" if data.get("time_unit") else f"time ({source})"

    def unit(self, name: str) -> str | None:
        own = (self.quantities.get(name) or {}).get("unit")
        base, order = split_derivative(name)
        declared = (self.quantities.get(base) or {}).get("unit") if order else None
        if own is not None or declared is None:
            return own
        return f"{declared} per {self.time_unit}" + ("²" if order == 2 else "")

    def label(self, name: str) -> str:
        unit = self.unit(name)
        if unit is not None:
            return f"{name} [{unit}]"
        base, order = split_derivative(name)
        if (self.quantities.get(name) or {}).get("quantity") is not None:
            return f"{name} ({self.quantities[name]['quantity']}, unit not declared)"
        if (self.quantities.get(base) or {}).get("quantity") is not None:
            rate = {1: "rate of ", 2: "second derivative of "}[order]
            return f"{name} ({rate}{self.quantities[base]['quantity']}, unit not declared)"
        if base in self.columns:
            return f"{name} ({'' if order == 0 else f'd{order}/dt{order} of '}column {self.columns[base]})"
        return f"{name} (no unit declared)"

    def ratio(self, output: str, input_: str) -> str:
        a, b = self.unit(output), self.unit(input_)
        return f"|{output} / {input_}|" + (f" [{a}/{b}]" if a and b else " (no units declared)")

    def frequency(self) -> str:
        return f"frequency (cycles per {self.time_unit})"
