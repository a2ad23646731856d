"""One Python front door in the style of scikit-learn and PySINDy: ``MSAM(model_config,
**options).fit(data)``, ``.diagnose(data)``, ``.simulate(...)``, ``.predict(...)``, ``.score(data)``.

The estimator runs the functional :func:`msam_torch.run.adapt.adapt` and
:func:`msam_torch.diagnosis.diagnose` (the same numbers); ``options`` are keys of the config's
``data`` and ``adaptation`` sections by name (``MSAM(config, preset="paper", refinement_steps=300)``).
Data are CSV/Parquet paths, pandas DataFrames, mappings of column to array, Datasets, or 2-D
tensors or arrays whose columns are the time column then ``data.columns`` in order.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from msam_torch.config.schema import Config, RangeConfig, load_config
from msam_torch.data.loading import DataArgument, resolve_datasets
from msam_torch.diagnosis.options import DiagnoseOptions
from msam_torch.diagnosis.report.gap_report import GapReport
from msam_torch.diagnosis.stages.pipeline import diagnose
from msam_torch.errors import ConfigError, DataError, MSAMError
from msam_torch.run.adapt import adapt
from msam_torch.run.plan import prepare, records_measured, with_options
from msam_torch.run.result import RunResult
from msam_torch.run.state_model import StateModel


class MSAM:
    """Model Structure Adaptation (Algorithm 1) of ``model_config`` (a YAML path, a mapping or a
    :class:`~msam_torch.config.schema.Config`; ``overrides`` as ``key.path=value``) with ``options`` set.

    After :meth:`fit`: ``result_`` (the :class:`~msam_torch.run.result.RunResult`) and ``model_``
    (the adapted :class:`~msam_torch.run.state_model.StateModel`); after :meth:`diagnose`: ``report_``.
    ``diagnose_options``: a :class:`~msam_torch.diagnosis.DiagnoseOptions` or a mapping of its fields.
    Paths in the config are relative to ``base_dir`` (default: the config file's folder)."""

    def __init__(self, model_config: Config | dict | str | Path, *, overrides: list[str] = (),
                 base_dir: str | Path | None = None, diagnose_options: DiagnoseOptions | dict | None = None,
                 **options):
        if isinstance(model_config, Config) and overrides:
            raise ConfigError("overrides", "apply overrides to a YAML path or a mapping, not to a Config "
                                           "(or give the keys as options)")
        config = model_config if isinstance(model_config, Config) else load_config(model_config, overrides)
        self.config = with_options(config, **options)
        self.base_dir = Path(base_dir if base_dir is not None else
                             Path(model_config).parent if isinstance(model_config, (str, Path)) else ".")
        self.diagnose_options = _diagnose_options(diagnose_options)

    def fit(self, data: DataArgument = None, validation: DataArgument = None) -> "MSAM":
        """Adapt the model to ``data`` (default: the config's record), scoring ``validation`` too."""
        self.result_ = adapt(self.config, data=self._table(data, "data"), validation=self._table(validation, "validation"),
                             base_dir=self.base_dir)
        self.model_ = self.result_.model()
        return self

    def diagnose(self, data: DataArgument = None, validation: DataArgument = None) -> GapReport:
        """The gap report of the starting model on ``data`` (held out: ``validation``)."""
        self.report_ = diagnose(self.config, self._table(data, "data"), self._table(validation, "validation"),
                                options=self.diagnose_options, base_dir=self.base_dir)
        return self.report_

    def model(self, stage: str = "adapted") -> StateModel:
        """The fitted model of ``stage`` (``start``, ``retuned``, ``adapted``, ``adapted_retuned``)."""
        return self._result().model(stage)

    def simulate(self, t, inputs, x0, stage: str = "adapted") -> torch.Tensor:
        """Free run of the model of ``stage`` (:meth:`StateModel.simulate`): states (N, S)."""
        return self.model(stage).simulate(t, inputs, x0)

    def predict(self, t, x, inputs=None, stage: str = "adapted") -> torch.Tensor:
        """One-step rates of every equation (N, equations) from samples (:meth:`StateModel.predict`)."""
        return self.model(stage).predict(t, x, inputs)

    def score(self, data: DataArgument, stage: str = "adapted") -> float:
        """Coefficient of determination R^2 of the free run on ``data``: the model of ``stage`` is
        simulated from the record's first (estimated) state under its inputs, and ``1 - sum (x -
        xhat)^2 / sum (x - mean x)^2`` is averaged over the measured states (1 is perfect; a run
        that diverges scores -inf). The whole record is scored: the config's ``data.train``,
        ``data.validation`` and ``data.validation_file`` do not apply to it."""
        result = self._result()
        config = load_config(result.config)
        data = self._table(data, "data")
        plan = prepare(config, in_memory=data is not None, measured=records_measured(config, data))
        whole = config.data.model_copy(update={"train": RangeConfig(), "validation": None, "validation_file": None})
        record, _ = resolve_datasets(whole, plan.spec, self.base_dir, plan.dtype, data, None, plan.derivatives)
        model = result.model(stage)
        signals = record.signals
        with torch.no_grad():
            states = model.simulate(signals["t"], {name: signals[name] for name in model.inputs},
                                    torch.stack([signals[x][0] for x in model.states]))
        measured = [x for x in model.states if x in (record.measured or signals)] or list(model.states)
        r2 = []
        for x in measured:
            truth, simulated = signals[x], states[:, model.states.index(x)]
            residual = float((truth - simulated).square().sum())
            r2.append(1 - residual / float((truth - truth.mean()).square().sum()) if np.isfinite(residual) else -np.inf)
        return float(np.mean(r2))

    def equations(self) -> list[str]:
        """The adapted equations as printed by ``msam run``."""
        return [e.equation for e in self._result().equations]

    def __str__(self) -> str:
        return "\n".join(self.equations()) if hasattr(self, "result_") else "MSAM (not fitted)"

    def _result(self) -> RunResult:
        if not hasattr(self, "result_"):
            raise MSAMError("MSAM: not fitted yet; call fit(data) first")
        return self.result_

    def _table(self, data, key: str):
        """A 2-D tensor or array as a mapping of column name to values (time column, then the
        ``data.columns`` in order); anything else as it is."""
        if not (torch.is_tensor(data) or isinstance(data, np.ndarray)):
            return data
        d = self.config.data
        names = ([d.time] if d.time else []) + list(d.columns.values())
        if not d.columns:
            raise ConfigError("data.columns", f"{key}: a tensor's columns are named by data.time and data.columns; give them")
        if data.ndim != 2 or data.shape[1] != len(names):
            raise DataError(f"{key}: expected a 2-D tensor with the columns {names}, got shape {tuple(data.shape)}")
        return {name: data[:, i] for i, name in enumerate(names)}


def _diagnose_options(options: DiagnoseOptions | dict | None) -> DiagnoseOptions:
    if options is None or isinstance(options, DiagnoseOptions):
        return options or DiagnoseOptions()
    fields = DiagnoseOptions.__dataclass_fields__
    for key in options:
        if key not in fields:
            raise ConfigError(f"diagnose_options.{key}", f"unknown option (known: {', '.join(fields)})")
    return DiagnoseOptions(**options)
