"""Long fixed-step runs integrated in segments side by side (:func:`msam_torch.simulation.solver.segments`):
the same trajectories as the sequential loop, in few passes where the model forgets its start,
in one pass per segment where it never does, diverged members marked as before, and never where
autograd differentiates the run."""
import math

import torch

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.simulation import solver
from msam_torch.simulation.equations import EquationModel, _system, simulate_equations

MODEL = {"states": ["x", "x_dot"], "inputs": ["u"], "parameters": {"c": 1.0, "k": 4.0},
         "equations": [{"target": "x_ddot", "components": [{"term": "x_dot", "theta": "-c"}, {"term": "x", "theta": "-k"},
                                                          {"term": "u", "theta": "1"}],
                        "adjustments": ["abs(x)", "abs(x_dot)"]}]}
N, DT = 601, 0.1  # 600 steps at the sample period: 6 segments of 100 steps (10 s) each


def _run(rows: list[list[float]], monkeypatch, sequential: bool) -> tuple[dict, int]:
    """Free runs of the oscillator with these theta rows (damping, stiffness, gain) under a
    multisine, sequential or segmented; and the passes the segments took."""
    spec = to_spec(load_config({"model": MODEL}).model)
    t = torch.arange(N, dtype=torch.float64) * DT
    u = sum(torch.sin(2 * math.pi * f * t + f) for f in (0.05, 0.13, 0.31, 0.7))
    passes = []
    joined = solver._joined
    monkeypatch.setattr(solver, "_joined", lambda *a: passes.append(1) or joined(*a))
    monkeypatch.setattr(solver, "SEGMENT_STEPS", 10 ** 9 if sequential else 100)
    model = EquationModel.starting(spec.equations[0], torch.tensor(rows, dtype=torch.float64))
    out = simulate_equations(spec, [model], t, {"u": u}, {"x": 0.2, "x_dot": -0.1}, step=DT, scale={"x": 1.0, "x_dot": 1.0})
    return out, len(passes)


def _close(a: dict, b: dict, rtol: float) -> None:
    for name in a:
        scale = b[name].nan_to_num(0.0).abs().amax(-1, keepdim=True)
        assert torch.equal(a[name].isnan(), b[name].isnan())
        assert float(((a[name] - b[name]).nan_to_num(0.0).abs() - rtol * scale).max()) <= 0.0


def test_a_damped_model_joins_its_segments_in_few_passes_and_matches_the_sequential_run(monkeypatch):
    rows = [[-4.0, -8.0, 1.0], [-3.0, -20.0, 1.2], [-5.0, -6.0, 0.8]]  # slowest decays 2, 1.5 and 2 per second
    sequential, none = _run(rows, monkeypatch, sequential=True)
    segmented, passes = _run(rows, monkeypatch, sequential=False)
    # 6 segments of 10 s each: a guessed start is forgotten to about e^-15 within one segment, more
    # than the 1.5e-8 they join within, and that error to e^-30 within the next: three passes
    assert none == 0 and passes == 3
    _close(segmented, sequential, 1e-7)
    assert float(sequential["x"].abs().max()) > 0.1  # the runs move


def test_a_model_that_never_forgets_its_position_needs_one_pass_per_segment_and_still_matches(monkeypatch):
    rows = [[-1.0, 0.0, 1.0], [-0.5, 0.0, 1.0]]  # no stiffness: the position integrates the speed
    sequential, _ = _run(rows, monkeypatch, sequential=True)
    segmented, passes = _run(rows, monkeypatch, sequential=False)
    assert passes == 6
    _close(segmented, sequential, 1e-7)


def test_a_diverging_member_is_marked_diverged_as_in_the_sequential_run(monkeypatch):
    rows = [[-4.0, -8.0, 1.0], [0.3, -4.0, 1.0]]  # negative damping: the second row grows beyond the span
    sequential, _ = _run(rows, monkeypatch, sequential=True)
    segmented, _ = _run(rows, monkeypatch, sequential=False)
    assert bool(sequential["x"][1].isnan().all()) and not bool(sequential["x"][0].isnan().any())
    _close(segmented, sequential, 1e-7)


def test_a_run_differentiated_by_autograd_is_not_segmented():
    spec = to_spec(load_config({"model": MODEL}).model)
    model = EquationModel.starting(spec.equations[0], torch.tensor([[-1.0, -4.0, 1.0]], dtype=torch.float64))
    _, p, _ = _system(spec, [model])
    t = torch.arange(N, dtype=torch.float64) * DT
    record = solver.Record(t, torch.zeros(N, 1, dtype=torch.float64), t.new_zeros(0, N), t.new_zeros(2))
    x0, steps = torch.zeros(1, 2, dtype=torch.float64), 6 * solver.SEGMENT_STEPS
    assert solver.segments(steps, x0, p, record) == 6
    assert solver.segments(steps, x0.requires_grad_(), p, record) == 1
    with torch.no_grad():  # a parameter that is not differentiated here
        assert solver.segments(steps, x0, p, record) == 6
