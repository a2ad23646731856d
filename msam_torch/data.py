"""Measurements in: the signals every equation reads, from a simulated system or measured data.

A *signal* is a 1-D tensor over the samples: states, inputs, their time derivatives and ``t``.
"""
from __future__ import annotations

import torch

from .config import DataConfig
from .errors import ConfigError
from .spec import ModelSpec
from .systems import get_system, simulate


def load_signals(config: DataConfig, spec: ModelSpec, dtype=torch.float64) -> tuple[dict[str, torch.Tensor], dict]:
    """Signals for ``spec`` and a provenance record (what was loaded, how derivatives were made)."""
    if config.system is None:
        raise ConfigError("data", "name a simulated 'system' or a measured data 'file'")
    system = get_system(config.system)
    signals = simulate(system, dtype=dtype)
    missing = sorted(spec.signals - set(signals))
    if missing:
        raise ConfigError("model", f"system {config.system!r} has no signals {missing} (it has {sorted(signals)})")
    if config.derivatives != "exact":
        raise ConfigError("data.derivatives", "only 'exact' derivatives are available for simulated systems here")
    return signals, {"source": f"system:{config.system}", "samples": int(signals["t"].numel()),
                     "derivatives": config.derivatives}
