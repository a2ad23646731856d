"""Forward-mode sensitivities through the fixed-step solver against central finite differences."""
import torch

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.simulation.configured import load_records, output_states
from msam_torch.simulation.ode import build_model
from msam_torch.simulation.problem import SimulationData
from msam_torch.simulation.sensitivities import jacobians
from tests.simulation.test_simulation_mode import TANKS, torricelli_record


def tanks(tmp_path, method):
    torricelli_record(tmp_path / "tanks.csv", n=40)
    config = load_config(TANKS, [f"adaptation.simulation.method={method}"])
    spec = to_spec(config.model)
    model = build_model(spec, spec.equations)
    record, _ = load_records(config, spec, model, output_states(config, spec, model), tmp_path)
    x0 = torch.tensor([[2.0, 3.0]], dtype=torch.float64)
    return SimulationData(model, record, (1,), x0, torch.ones(1, 2, dtype=torch.float64),
                          torch.ones(6, dtype=torch.bool), method)


def central(f, x: torch.Tensor, j: int, h: float) -> torch.Tensor:
    step = torch.zeros_like(x)
    step[..., j] = h
    return (f(x + step) - f(x - step)) / (2 * h)


def test_exact_sensitivities_match_central_differences(tmp_path):
    """d yhat / d (theta, theta_fixed, initial states) by forward mode through rk4 and midpoint agree
    with central differences to 1e-6 relative, dM (Eq. 15) with the one built from them, and the
    change of Eq. 16 is the simulated one."""
    for method in ("rk4", "midpoint"):
        data = tanks(tmp_path, method)
        choice = torch.tensor([[[0, 0, 1]]])
        gamma = torch.tensor([[[-0.3, -0.4, -0.2]]], dtype=torch.float64)
        z = torch.tensor([[[-0.08, 0.08, -0.07, 0.05, 2.0, 3.0]]], dtype=torch.float64)
        jac = jacobians(data, choice, gamma, z, dgamma=1e-2)
        output = lambda g, zz: data.output(g, choice, zz[..., :3], zz[..., 3:4], zz[..., 4:])
        torch.testing.assert_close(jac.base, output(gamma, z), rtol=0, atol=0)
        by_z = torch.stack([central(lambda v: output(gamma, v), z, j, 1e-6) for j in range(6)], -1)
        assert by_z.abs().amax() > 1.0
        assert float(((jac.z - by_z).abs() / by_z.abs().amax(-2, keepdim=True)).max()) < 1e-6  # per column
        change = torch.stack([output(gamma + 1e-2 * torch.eye(3, dtype=gamma.dtype)[i], z) - output(gamma, z)
                              for i in range(3)], -1)
        assert change.abs().amax() > 0.01
        torch.testing.assert_close(jac.change, change, rtol=1e-12, atol=1e-15)
        theta_sensitivity = lambda g: torch.stack([central(lambda v: output(g, v), z, j, 1e-6) for j in range(3)], -1)
        s = theta_sensitivity(gamma)
        shifted = [theta_sensitivity(gamma + 1e-2 * torch.eye(3, dtype=gamma.dtype)[i]) for i in range(3)]
        dm = torch.stack([torch.linalg.vector_norm(x - s, dim=-1).sum(-1) for x in shifted], -1) \
            / torch.linalg.vector_norm(s, dim=-1).sum(-1, keepdim=True)
        assert float(dm.min()) > 1e-3
        torch.testing.assert_close(jac.dm, dm, rtol=1e-5, atol=0)


def test_sensitivities_without_dm_are_the_same_rows(tmp_path):
    """Without dM (a step in exponent units) the shifted exponents are simulated once each: the
    change of Eq. 16 and the free columns are those of the full pass, dM is NaN; with no free
    column the base row is still simulated."""
    data = tanks(tmp_path, "midpoint")
    choice = torch.tensor([[[0, 0, 1], [1, 0, 0]]])
    gamma = torch.tensor([[[-0.3, -0.4, -0.2], [0.5, 0.1, 0.0]]], dtype=torch.float64)
    z = torch.tensor([[[-0.08, 0.08, -0.07, 0.05, 2.0, 3.0]]], dtype=torch.float64).expand(1, 2, 6)
    free = torch.tensor([False] * 4 + [True, True])
    full = jacobians(data, choice, gamma, z, 1e-2, free)
    lean = jacobians(data, choice, gamma, z, 1e-2, free, dm=False)
    torch.testing.assert_close(lean.change, full.change, rtol=1e-13, atol=1e-15)
    torch.testing.assert_close(lean.z[..., free], full.z[..., free], rtol=1e-13, atol=1e-15)
    torch.testing.assert_close(lean.base, full.base, rtol=0, atol=0)
    assert bool(torch.isnan(lean.dm).all()) and bool(torch.isfinite(full.dm).all())
    none = jacobians(data, choice, gamma, z, 1e-2, torch.zeros(6, dtype=torch.bool), dm=False)
    torch.testing.assert_close(none.base, full.base, rtol=0, atol=0)
    torch.testing.assert_close(none.change, full.change, rtol=1e-13, atol=1e-15)
