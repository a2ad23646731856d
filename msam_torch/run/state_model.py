"""A model you can hold: the state equations of a result (Eq. 9, ``sum_i theta_i M_i f_i^gamma_i +
sum_j theta_j M_j``) as an ``nn.Module`` ``f(t, x)`` for :func:`torchdiffeq.odeint`.

The right-hand side is the package's one Eq. 9 model (:class:`msam_torch.simulation.ode.SystemModel`);
inputs (and states no equation simulates) are interpolated from the samples given to
:meth:`StateModel.with_inputs` as in a simulation record (``simulation.input_hold``). Theta and
the exponents are parameters (trainable, moved and cast by ``.to()``); the choice of adjustment
function per component is a buffer, so ``state_dict()`` holds the whole model.
"""
from __future__ import annotations

import ast
from dataclasses import dataclass, replace

import torch
from torch import nn

from msam_torch.config.schema import Config, load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.errors import ConfigError
from msam_torch.model.expressions import Expression
from msam_torch.model.spec import ModelSpec, split_derivative
from msam_torch.simulation.configured import state_limits
from msam_torch.simulation.ode import Parameters, build_model
from msam_torch.simulation.record import Record
from msam_torch.simulation.solver import simulate

STAGES = ("start", "retuned", "adapted", "adapted_retuned")


@dataclass(frozen=True)
class Stage:
    """One stage of every equation: per component the adjustment text (None: unadjusted), the
    exponent gamma (None: unadjusted) and theta in the data's units."""

    adjustments: tuple[list, ...]
    exponents: tuple[list, ...]
    theta: tuple[list, ...]


def result_stage(spec: ModelSpec, equations: list, data: dict, stage: str) -> Stage:
    """``stage`` of a run's :class:`~msam_torch.run.result.EquationResult` list (``data``: the run's
    provenance): ``start`` (nominal theta), ``retuned`` (starting structure, theta re-estimated),
    ``adapted``, ``adapted_retuned`` (adapted structure, theta re-estimated; one-step runs)."""
    if stage not in STAGES:
        raise ConfigError("stage", f"unknown stage {stage!r} (choose from {', '.join(STAGES)})")
    none = tuple([None] * len(e.theta) for e in equations)
    if stage == "start":
        nominal = data.get("nominal_parameters", spec.parameters)
        return Stage(none, none, tuple(spec.theta(eq, nominal).tolist() for eq in spec.equations))
    simulated = {t: th for group in data.get("simulation", []) for t, th in group.get("retuned_theta", {}).items()}
    if stage == "retuned" and all(e.target in simulated for e in equations):
        return Stage(none, none, tuple(simulated[e.target] for e in equations))
    if stage in ("retuned", "adapted_retuned") and not all(e.theta_tuning for e in equations):
        raise ConfigError("stage", f"this run has no stage {stage!r} (theta was not re-estimated)")
    if stage == "retuned":
        return Stage(none, none, tuple(e.theta_tuning["retuned"]["theta"] for e in equations))
    theta = [e.theta_tuning["adapted_retuned"]["theta"] if stage == "adapted_retuned" else e.theta for e in equations]
    return Stage(tuple(e.adjustments for e in equations), tuple(e.exponents for e in equations), tuple(theta))


REPORT_STAGES = ("start", "retuned", "adapted")  # the rows of a diagnosis's models (diagnose.compare.models)


def report_stage(models: list, stage: str | tuple[str, ...]) -> Stage:
    """``stage`` (``start``, ``retuned``, ``adapted``; or one per equation) of a diagnosis from its
    equations' extended-form :class:`~msam_torch.simulation.equations.EquationModel` (one row per stage): per
    component of the extended equation the adjustment, exponent and theta in the data's units."""
    stages = (stage,) * len(models) if isinstance(stage, str) else stage
    for s in stages:
        if s not in REPORT_STAGES:
            raise ConfigError("stage", f"unknown stage {s!r} of a diagnosis (choose from "
                                       f"{', '.join(REPORT_STAGES + ('accepted',))})")
    adjustments, exponents, thetas = [], [], []
    for model, s in zip(models, stages):
        row = REPORT_STAGES.index(s)
        eq = model.equation
        adjustment, exponent, theta = [None] * len(eq.components), [None] * len(eq.components), [0.0] * len(eq.components)
        for k, i in enumerate(eq.adjustable):
            choice, gamma = int(model.choice[row, k]), float(model.gamma[row, k])
            theta[i] = float(model.theta[row, k])
            if choice >= 0:  # theta of |f / scale|^gamma in the units of |f|^gamma
                adjustment[i], exponent[i] = eq.adjustments[choice].text, gamma
                theta[i] *= float(model.scale[choice]) ** -gamma
        for k, i in enumerate(eq.fixed):
            theta[i] = float(model.theta_fixed[row, k])
        adjustments.append(adjustment)
        exponents.append(exponent)
        thetas.append(theta)
    return Stage(tuple(adjustments), tuple(exponents), tuple(thetas))


class StateModel(nn.Module):
    """``f(t, x) -> dx/dt`` of the simulated states (``states``) for ``torchdiffeq.odeint``.

    ``x``: (..., S) in the order of :attr:`states`; inputs from :meth:`with_inputs`. ``limits``
    (2, S): ``simulation.saturation`` (a state's rate is zero at a limit when pointing outwards).
    """

    def __init__(self, spec: ModelSpec, stage: Stage, dtype=torch.float64, hold: str = "linear",
                 limits: torch.Tensor | None = None, method: str = "rk4", substeps: int = 1):
        super().__init__()
        self.spec, self.hold, self.method, self.substeps = spec, hold, method, substeps
        self.system = build_model(spec, spec.equations)
        texts = [f.text for f in self.system.functions]
        rows = [(self.system.unadjusted if stage.adjustments[e][i] is None else texts.index(stage.adjustments[e][i]),
                 float(stage.exponents[e][i] or 0.0), float(stage.theta[e][i])) for e, i in self.system.adjustable]
        tensor = lambda values, kind=dtype: torch.tensor(values, dtype=kind).reshape(1, -1)
        self.register_buffer("choice", tensor([r[0] for r in rows], torch.long))
        self.gamma = nn.Parameter(tensor([r[1] for r in rows]))
        self.theta = nn.Parameter(tensor([r[2] for r in rows]))
        self.theta_fixed = nn.Parameter(tensor([float(stage.theta[e][i]) for e, i in self.system.fixed]))
        self.register_buffer("limits", limits, persistent=False)
        self.register_buffer("input_t", torch.zeros(0, dtype=dtype), persistent=False)
        self.register_buffer("input_values", torch.zeros(0, len(self.system.external), dtype=dtype), persistent=False)
        self.register_buffer("input_pieces", None, persistent=False)

    @classmethod
    def from_result(cls, result, stage: str = "adapted", dtype=torch.float64) -> "StateModel":
        """The model of ``stage`` of a :class:`~msam_torch.run.result.RunResult`."""
        config = result.config if isinstance(result.config, Config) else load_config(result.config)
        spec = to_spec(config.model)
        sim = config.adaptation.simulation
        limits = state_limits(config, build_model(spec, spec.equations).states, dtype)
        return cls(spec, result_stage(spec, result.equations, result.data, stage), dtype, sim.input_hold, limits,
                   sim.method, sim.substeps)

    @classmethod
    def from_report(cls, report, stage: str = "adapted", dtype=torch.float64) -> "StateModel":
        """The model of ``stage`` of a :class:`~msam_torch.diagnosis.GapReport`: its equations
        extended by the fitted effect term (the diagnosis's models, Eq. 9); ``accepted``: the model
        with every effect added in turn (``report.in_turn``)."""
        if not report.models:
            raise ConfigError("stage", "this report holds no fitted models (a report read back from JSON, "
                                       "or a diagnosis by simulation): diagnose again to get them")
        config, models = load_config(report.config), report.models
        if stage == "accepted":
            if not report.accepted:
                raise ConfigError("stage", "no effects were added in turn (diagnose with max_effects above 1): "
                                           "the adapted model is the final one")
            config, models, stage = load_config(report.accepted["config"]), report.accepted["models"], report.accepted["stages"]
        sim = config.adaptation.simulation
        extended = tuple(m.equation for m in models)
        spec = replace(to_spec(config.model), equations=extended)
        limits = state_limits(config, build_model(spec, extended).states, dtype)
        return cls(spec, report_stage(models, stage), dtype, sim.input_hold, limits, sim.method, sim.substeps)

    @property
    def states(self) -> tuple[str, ...]:
        """The simulated states, the order of ``x``."""
        return self.system.states

    @property
    def inputs(self) -> tuple[str, ...]:
        """The interpolated signals (inputs, then states read from data), the columns of the samples."""
        return self.system.external

    def parameters_of(self) -> Parameters:
        """The model's parameters as one simulated row (Eq. 9, unscaled functions)."""
        scale = torch.ones(1, len(self.system.functions), dtype=self.theta.dtype, device=self.theta.device)
        return Parameters(self.gamma, self.choice, self.theta, self.theta_fixed, scale)

    def with_inputs(self, t, inputs) -> "StateModel":
        """Attach input samples at times ``t`` (N,) on a uniform grid: (N, E) in the order of
        :attr:`inputs`, or a mapping of name to (N,) values. Returns ``self``."""
        t = torch.as_tensor(t, dtype=self.theta.dtype, device=self.theta.device)
        if isinstance(inputs, dict):
            missing = [n for n in self.inputs if n not in inputs]
            if missing:
                raise ConfigError("inputs", f"missing the signals {missing} (the model reads {list(self.inputs)})")
            inputs = torch.stack([torch.as_tensor(inputs[n]).reshape(-1) for n in self.inputs], -1) \
                if self.inputs else torch.zeros(t.shape[0], 0)
        inputs = torch.as_tensor(inputs, dtype=t.dtype, device=t.device).reshape(t.shape[0], len(self.inputs))
        record = Record.build(t, inputs, inputs[:0].T, inputs[0, :0], self.hold)
        self.input_t, self.input_values, self.input_pieces = record.t, record.external, record.pieces
        return self

    def _record(self) -> Record:
        return Record(self.input_t, self.input_values, self.input_values[:0].T, self.input_t[:0], self.hold,
                      self.input_pieces)

    def _external(self, t: torch.Tensor):
        if not self.inputs:
            return ()
        if self.input_t.shape[0] < 2:
            raise ConfigError("inputs", f"the model reads {list(self.inputs)}: give samples with with_inputs(t, inputs)")
        return self._record().at(t.reshape(1)).squeeze(-2).unbind(-1)

    def forward(self, t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """``dx/dt`` (..., S) at time ``t`` (a scalar tensor) by Eq. 9."""
        t = torch.as_tensor(t, dtype=x.dtype, device=x.device)
        flat = x.reshape(-1, x.shape[-1])
        rows = lambda v: v.expand(flat.shape[:-1])  # per row, as the states (no data-dependent checks of scalars)
        values = {"t": rows(t), **dict(zip(self.states, flat.unbind(-1))),
                  **{name: rows(v) for name, v in zip(self.inputs, self._external(t))}}
        rate = self.system.rhs(self.parameters_of(), x.dtype, x.device)(values, flat)
        if self.limits is not None:
            held = ((flat >= self.limits[1]) & (rate > 0)) | ((flat <= self.limits[0]) & (rate < 0))
            rate = torch.where(held, torch.zeros_like(rate), rate)
        return rate.reshape(x.shape)

    def simulate(self, t, inputs, x0) -> torch.Tensor:
        """Free run from ``x0`` (S,) or (B, S) over ``t`` (N,) under ``inputs`` (see
        :meth:`with_inputs`) with the package's solver and the config's method: (N, S) or (B, N, S)."""
        self.with_inputs(t, inputs if self.inputs else torch.zeros(len(torch.as_tensor(t)), 0))
        x0 = torch.as_tensor(x0, dtype=self.theta.dtype, device=self.theta.device)
        batch = x0.reshape(-1, x0.shape[-1])
        states = simulate(self.system, self._record(), self.parameters_of(), batch, self.method, self.substeps,
                          self.limits)
        return states[0] if x0.dim() == 1 else states

    def predict(self, t, x, inputs=None) -> torch.Tensor:
        """One-step rates: each equation's modelled target (N, equations) from samples of the
        states ``x`` (N, S) and ``inputs`` (N, E) at times ``t`` (N,), without interpolation."""
        x = torch.as_tensor(x, dtype=self.theta.dtype, device=self.theta.device)
        inputs = x[..., :0] if inputs is None else torch.as_tensor(inputs, dtype=x.dtype, device=x.device)
        values = self.system.values(torch.as_tensor(t, dtype=x.dtype, device=x.device), x, inputs)
        return self.system.equation_rates(self.parameters_of(), x.dtype, x.device)(values, x.shape[:-1])

    def terms(self) -> list[dict]:
        """Every component: equation target, term, theta, adjustment function and exponent."""
        adjustable = {k: j for j, k in enumerate(self.system.adjustable)}
        fixed = {k: j for j, k in enumerate(self.system.fixed)}
        rows = []
        for e, eq in enumerate(self.system.equations):
            for i, component in enumerate(eq.components):
                j = adjustable.get((e, i))
                chosen = None if j is None or int(self.choice[0, j]) == self.system.unadjusted \
                    else self.system.functions[int(self.choice[0, j])]
                theta = self.theta[0, j] if j is not None else self.theta_fixed[0, fixed[(e, i)]]
                rows.append({"equation": eq.target, "term": component.term.text, "theta": float(theta.detach()),
                             "function": None if chosen is None else chosen.text,
                             "exponent": None if chosen is None else float(self.gamma[0, j].detach())})
        return rows

    def extra_repr(self) -> str:
        """The equations of :meth:`to_sympy` to four significant digits, one per line: what
        ``print(model)`` shows (a diagnosis's unadjusted copies and constant functions simplified away)."""
        import sympy

        return "\n".join(f"{e.lhs} = {sympy.N(e.rhs, 4)}" for e in self.to_sympy())

    def to_frame(self):
        """The terms as a pandas DataFrame (one row per component)."""
        import pandas as pd

        return pd.DataFrame(self.terms())

    def to_sympy(self) -> list:
        """The state equations as ``sympy.Eq(target, rhs)``: ``theta M |f|^gamma`` (magnitude) or
        ``theta M sign(f)|f|^gamma`` (signed), Eq. 9."""
        import sympy

        functions = {f.text: f for f in self.system.functions}
        out = []
        for eq in self.system.equations:
            rhs = sympy.Integer(0)
            for row, component in zip([r for r in self.terms() if r["equation"] == eq.target], eq.components):
                term = sympy.Float(row["theta"], 17) * _sympy(component.term)
                if row["function"] is not None:
                    f = _sympy(functions[row["function"]])
                    magnitude = sympy.Abs(f) ** sympy.Float(row["exponent"], 17)
                    term = term * (magnitude if functions[row["function"]].is_magnitude else sympy.sign(f) * magnitude)
                rhs = rhs + term
            out.append(sympy.Eq(sympy.Symbol(eq.target), rhs))
        return out

    def to_latex(self) -> str:
        """The equations in LaTeX, one per line; a derivative's name as its dots (``x_ddot``: ``\\ddot{x}``)."""
        import sympy

        equations = self.to_sympy()
        names = {}
        for symbol in set().union(*(e.free_symbols for e in equations)):
            base, order = split_derivative(symbol.name)
            if 1 <= order <= 2:
                names[symbol] = f"\\{'d' * order}ot{{{sympy.latex(sympy.Symbol(base))}}}"
        return " \\\\\n".join(sympy.latex(e, symbol_names=names) for e in equations)


def _sympy(expression: Expression):
    """A parsed expression (whitelisted syntax tree) as a sympy expression, node by node (no eval)."""
    import sympy

    functions = {"abs": sympy.Abs, "sign": sympy.sign, "sqrt": sympy.sqrt, "exp": sympy.exp, "log": sympy.log,
                 "sin": sympy.sin, "cos": sympy.cos, "tanh": sympy.tanh}
    binary = {ast.Add: lambda a, b: a + b, ast.Sub: lambda a, b: a - b, ast.Mult: lambda a, b: a * b,
              ast.Div: lambda a, b: a / b, ast.Pow: lambda a, b: a**b}

    constants = dict(expression.constants)

    def walk(node):
        if isinstance(node, ast.Constant):
            return sympy.Integer(node.value) if isinstance(node.value, int) else sympy.Float(node.value)
        if isinstance(node, ast.Name):
            return sympy.Float(constants[node.id], 17) if node.id in constants else sympy.Symbol(node.id)
        if isinstance(node, ast.BinOp):
            return binary[type(node.op)](walk(node.left), walk(node.right))
        if isinstance(node, ast.UnaryOp):
            return -walk(node.operand) if isinstance(node.op, ast.USub) else walk(node.operand)
        return functions[node.func.id](walk(node.args[0]))

    return walk(expression.tree)
