"""The residual checks' statistics without scipy.stats and statsmodels (msam_torch.diagnosis.stages.
structure): the Ljung-Box p-value equals statsmodels' acorr_ljungbox, the chi-square survival
function scipy's, and the nearest neighbours from every distance are the k-d tree's."""
import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree
from scipy.stats import chi2
from statsmodels.stats.diagnostic import acorr_ljungbox

from msam_torch.diagnosis.stages import structure
from msam_torch.diagnosis.stages.structure import chi2_sf, ljung_box, nearest


@pytest.mark.parametrize("n, lags", [(12, 1), (50, 3), (400, 10)])
def test_ljung_box_matches_statsmodels(n, lags):
    x = np.convolve(np.random.default_rng(n).standard_normal(n), [1.0, 0.4], "same")
    expected = float(acorr_ljungbox(x, lags=[lags])["lb_pvalue"].iloc[0])
    assert ljung_box(torch.tensor(x), lags) == pytest.approx(expected, rel=1e-10)


@pytest.mark.parametrize("x, df", [(0.5, 1), (3.0, 2), (30.0, 7), (200.0, 11), (1e-3, 40)])
def test_chi_square_survival_matches_scipy(x, df):
    assert chi2_sf(x, df) == pytest.approx(chi2.sf(x, df), rel=1e-12)


def test_nearest_neighbours_from_every_distance_are_the_k_d_trees(monkeypatch):
    rng = np.random.default_rng(0)
    points, queries = rng.standard_normal((300, 3)), rng.standard_normal((200, 3))
    _, expected = cKDTree(points).query(queries, k=list(range(1, 11)))
    brute = nearest(torch.tensor(points), torch.tensor(queries), 10)
    assert 300 * 200 <= structure.BRUTE_FORCE and torch.equal(brute, torch.as_tensor(expected))
    monkeypatch.setattr(structure, "BRUTE_FORCE", 0)  # beyond it: the k-d tree itself
    assert torch.equal(nearest(torch.tensor(points), torch.tensor(queries), 10), brute)
