"""Step grids kept for reuse (msam_torch.simulation.grids): a step's sensitivities read the rows an
evaluation integrated (with its probe of the shifted exponents) and are the same to the last bit as
those of a problem that keeps nothing; a row kept under another record is not read."""
from dataclasses import replace

import torch

from msam_torch.simulation.grids import Grids
from msam_torch.simulation.sensitivities import jacobians
from tests.simulation.test_simulation_sensitivities import tanks


def counted(grids: Grids) -> dict:
    """Count the rows asked for and found in ``grids``."""
    counts = {"asked": 0, "found": 0}
    take = grids.take

    def counting(context, keys):
        hit, kept = take(context, keys)
        counts["asked"] += keys.shape[0]
        counts["found"] += int(hit.sum())
        return hit, kept
    grids.take = counting
    return counts


def test_sensitivities_read_the_probed_rows_and_equal_a_fresh_run(tmp_path):
    data = tanks(tmp_path, "midpoint")
    counts = counted(data.grids)
    choice = torch.tensor([[[0, 0, 1], [1, 0, 0]]])
    gamma = torch.tensor([[[-0.3, -0.4, -0.2], [0.5, 0.1, -0.2]]], dtype=torch.float64)
    z = torch.tensor([[[-0.08, 0.08, -0.07, 0.05, 2.0, 3.0]] * 2], dtype=torch.float64)
    out = data.output(gamma, choice, z[..., :3], z[..., 3:4], z[..., 4:], probe=1e-2)
    fresh = replace(data, grids=Grids())
    torch.testing.assert_close(out, fresh.output(gamma, choice, z[..., :3], z[..., 3:4], z[..., 4:]), rtol=0, atol=0)
    asked = counts["asked"]
    for dm in (False, True):
        kept, new = (jacobians(d, choice, gamma, z, dgamma=1e-2, dm=dm) for d in (data, fresh))
        for name in ("change", "z", "base"):
            torch.testing.assert_close(getattr(kept, name), getattr(new, name), rtol=0, atol=0)
        torch.testing.assert_close(kept.dm, new.dm, rtol=0, atol=0, equal_nan=True)
    assert counts["asked"] - asked == 2 * 2 * 4  # two passes of 2 candidates at Gamma and its 3 shifts ...
    assert counts["found"] - counts["asked"] + asked == 0  # ... all read, none integrated again


def test_rows_kept_under_another_record_are_not_read(tmp_path):
    data = tanks(tmp_path, "rk4")
    choice, gamma = torch.tensor([[0, 0, 1]]), torch.tensor([[-0.3, -0.4, -0.2]], dtype=torch.float64)
    z = torch.tensor([[-0.08, 0.08, -0.07, 0.05, 2.0, 3.0]], dtype=torch.float64)
    data.output(gamma, choice, z[..., :3], z[..., 3:4], z[..., 4:])
    shifted = replace(data.record, external=data.record.external * 2.0)
    other = replace(data, record=shifted)
    counts = counted(other.grids)
    out = other.output(gamma, choice, z[..., :3], z[..., 3:4], z[..., 4:])
    assert counts == {"asked": 1, "found": 0}
    expected = replace(other, grids=Grids()).output(gamma, choice, z[..., :3], z[..., 3:4], z[..., 4:])
    torch.testing.assert_close(out, expected, rtol=0, atol=0)
