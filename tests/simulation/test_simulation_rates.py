"""The solver's per-stage right-hand side (expressions that read no simulated state tabulated once)
against Eq. 9 evaluated from named signal values, on a model with every kind of column."""
import torch

from msam_torch.config.schema import ModelConfig
from msam_torch.config.to_spec import to_spec
from msam_torch.simulation.ode import Parameters, build_model

MODEL = {
    "states": ["x", "x_dot", "y"],
    "inputs": ["u"],
    "parameters": {"a": 2.0},
    "equations": [
        {"target": "x_ddot", "components": [{"term": "x_dot", "theta": "-a"}, {"term": "x*u", "theta": -1.0},
                                            {"term": "u", "theta": 0.5, "adjustable": False}],
         "adjustments": ["abs(x_dot)", "x", "sin(t) + 2"]},
        {"target": "y_dot", "components": [{"term": "y", "theta": -1.0}, {"term": "u", "theta": 1.0}],
         "adjustments": ["abs(u)", "y"]},
    ],
}


def test_stage_rates_equal_eq9_from_values():
    spec = to_spec(ModelConfig.model_validate(MODEL))
    model = build_model(spec, spec.equations)
    assert [x.text for x in model.columns.inner] == ["abs(x_dot)", "x*u"]
    assert [x.text for x in model.columns.outer] == ["sin(t) + 2", "abs(u)", "u"]
    generator = torch.Generator().manual_seed(0)
    b, k, q = 5, 7, len(model.adjustable)
    choice = torch.stack([torch.tensor([c[i % len(c)] for c in model.allowed]) for i in range(b - 1)]
                         + [torch.full((q,), model.unadjusted)])
    p = Parameters(torch.randn(b, q, generator=generator, dtype=torch.float64), choice,
                   torch.randn(b, q, generator=generator, dtype=torch.float64),
                   torch.randn(b, len(model.fixed), generator=generator, dtype=torch.float64),
                   torch.rand(b, len(model.functions), generator=generator, dtype=torch.float64) + 0.5)
    t = torch.linspace(0.0, 1.0, k, dtype=torch.float64)
    external = torch.randn(k, 1, generator=generator, dtype=torch.float64)
    x = torch.randn(b, 3, generator=generator, dtype=torch.float64)
    stage = model.stage_rates(p, t, external)
    rhs = model.rhs(p, torch.float64, None)
    for j in range(k):
        expected = rhs(model.values(t[j], x, external[j].expand(b, 1)), x)
        torch.testing.assert_close(stage(j, x), expected, rtol=1e-14, atol=1e-14)
    assert float(stage(0, x)[:, 0].sub(x[:, 1]).abs().max()) == 0.0  # the kinematic state x' = x_dot
