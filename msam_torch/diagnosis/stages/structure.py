"""Residual structure a hypothesis leaves: how much of the re-fitted start's held-out weak-form
residual a k-nearest-neighbour regression on the equation's signals predicts, before and after
the effect (a verdict check: an effect that leaves most of the structure does not explain the gap);
and the checks "no significant gap" needs (:func:`residual_checks`): the re-fitted start's
residual on non-overlapping test functions is white (Ljung-Box), uncorrelated with the inputs at
any lag, and holds little nearest-neighbour structure. A check that fails counts only for
structure relevant in size by the null rule (:func:`relevant`): a residual at the noise floor can
hold structure (correlated beyond chance on a long record, or the quadrature error of noise-free
data) whose removal would not lower its RMS by what an effect must."""
from __future__ import annotations

import math

import torch

from msam_torch.diagnosis.compare.confidence import significant
from msam_torch.diagnosis.effects.hypotheses import Fitted, predict_rows
from msam_torch.diagnosis.stages.rows import WeakForm
from msam_torch.engine.weak_form import TestFunctions
from msam_torch.model.spec import Equation

NEIGHBOURS = 10
LAGS = 10  # autocorrelation and input cross-correlation lags, at most
FEWEST_ROWS = 12  # independent rows the residual checks need
BRUTE_FORCE = 250_000  # query-point pairs up to which nearest neighbours come from every distance


def _features(equation: Equation, signals: dict, tests: TestFunctions):
    names = sorted(n for n in equation.signals - {equation.target, "t"} if n in signals)
    return names, torch.stack([tests.average(signals[n]) for n in names], -1)


def _explained(equation: Equation, weak: WeakForm, choices: torch.Tensor, original: Fitted,
               hypotheses: tuple[int, ...]) -> list[tuple[float, float]]:
    """Per hypothesis: the held-out residual's mean square that a k-nearest-neighbour regression of
    the training residual on the equation's signals predicts, and the residual's mean square."""
    _, x_fit = _features(equation, weak.signals, weak.tests)
    _, x_val = _features(equation, weak.val_signals, weak.val_tests)
    x_fit, x_val = x_fit[weak.fit_rows], x_val[weak.val_rows]
    spread = x_fit.std(0)
    varies = spread > 0  # a signal constant over the fitted rows (a held input) tells no rows apart
    scaled = lambda x: x[:, varies] / spread[varies] if bool(varies.any()) else torch.zeros_like(x[:, :1])
    neighbours = nearest(scaled(x_fit), scaled(x_val), min(NEIGHBOURS, x_fit.shape[0]))
    fit_pred = predict_rows(weak.data, choices, original)[0]  # rows of the weighted fit: weights are 0/1
    val_pred = predict_rows(weak.val_data, choices, original)[0]
    explained = []
    for c in hypotheses:
        r_fit = (weak.data.y[0] - fit_pred[c])[weak.fit_rows]
        r_val = (weak.val_data.y[0] - val_pred[c])[weak.val_rows]
        guess = r_fit[neighbours].mean(-1)
        explained.append((float(((r_val**2).mean() - ((r_val - guess) ** 2).mean()).clamp_min(0)),
                          float((r_val**2).mean())))
    return explained


def structure_left(equation: Equation, weak: WeakForm, choices: torch.Tensor, original: Fitted, best: int) -> float:
    """Share of the re-fitted start's residual structure (what a k-nearest-neighbour regression on
    the equation's signals predicts on held-out rows) that hypothesis ``best`` leaves."""
    (start, _), (effect, _) = _explained(equation, weak, choices, original, (0, best))
    return effect / start if start > 0 else 0.0


def residual_checks(equation: Equation, weak: WeakForm, choices: torch.Tensor, original: Fitted, inputs: list[str],
                    level: float, largest_structure: float, negligible: float, relative: float,
                    reach: int = 0, row_noise: float = 0.0) -> dict:
    """Whether the re-fitted start's held-out residual looks like noise: on rows of test functions
    apart by their length plus ``reach`` samples (the window of a derivative estimate; then the rows
    are independent under white measurement noise), the Ljung-Box p-value of its
    autocorrelation and the Bonferroni p-value of its largest cross-correlation with the inputs'
    window averages (lags up to :data:`LAGS`), each at least ``level``, and the share of its mean
    square a nearest-neighbour regression predicts at most ``largest_structure``, or the structure
    found not relevant (:func:`relevant`, the null rule's ``relative`` and ``negligible`` margins).
    A residual within ``negligible`` of the held-out target's RMS passes. On fewer than
    :data:`FEWEST_ROWS` independent rows (``unchecked``: too few to test for structure) the residual
    must be as small as the measurement noise makes it: ``row_noise`` (a row's noise standard
    deviation, at least ``negligible`` of the target's RMS) explains its sum of squares by the
    chi-square test at ``level`` (``noise_p``). ``failed`` names the checks missed."""
    residual = (weak.val_data.y[0] - predict_rows(weak.val_data, choices, original)[0, 0])
    rows = torch.nonzero(weak.val_rows).squeeze(-1)
    rows = rows[::weak.apart(reach)]
    out = {"independent_rows": int(rows.numel()), "ljung_box_p": None, "input_correlation_p": None,
           "structure_share": None, "failed": []}
    rms = float(residual[weak.val_rows].square().mean().sqrt())
    if rms <= negligible * weak.target_rms:
        return {**out, "negligible": True}
    if rows.numel() < FEWEST_ROWS:  # too few rows to test for structure: the residual must be the noise's size
        few = f"only {rows.numel()} independent held-out rows"
        floor = max(row_noise, negligible * weak.target_rms)
        out.update(unchecked=few, noise_p=chi2_sf(float(residual[rows].square().sum()) / floor**2, rows.numel()))
        if out["noise_p"] < level:
            out["failed"].append(f"{few}, too few to test the re-fitted start's residual for structure, and it is "
                                 f"{rms / floor:.3g} times what the measurement noise explains "
                                 f"(chi-square p = {out['noise_p']:.2g})")
        return out
    u = [weak.val_tests.average(weak.val_signals[name])[rows] for name in inputs]
    out.update(whiteness(residual[rows], u, level, weak.target_rms, relative, negligible))
    explained, total = _explained(equation, weak, choices, original, (0,))[0]
    out["structure_share"] = explained / total if total > 0 else 0.0
    if out["structure_share"] > largest_structure and relevant(out["structure_share"], rms, weak.target_rms,
                                                               relative, negligible):
        out["failed"].append(f"the signals predict {100 * out['structure_share']:.0f} % of the re-fitted start's "
                             "residual (nearest neighbours)")
    return out


def relevant(share: float, rms: float, target_rms: float, relative: float, absolute: float) -> bool:
    """Whether removing ``share`` of a residual's mean square (RMS ``rms``) would lower its RMS by the
    null rule's margins (:func:`~msam_torch.diagnosis.compare.confidence.significant`): structure a test finds beyond chance that
    no effect could remove by a relevant amount is no gap."""
    rms = torch.tensor(rms, dtype=torch.float64)
    return bool(significant(rms * math.sqrt(max(0.0, 1.0 - share)), rms, target_rms, relative, absolute))


def whiteness(residual: torch.Tensor, inputs: list[torch.Tensor], level: float, target_rms: float,
              relative: float, absolute: float) -> dict:
    """Whether independent samples of the re-fitted start's residual look like white noise: the Ljung-Box
    p-value of its autocorrelation and the Bonferroni p-value of its largest cross-correlation
    with ``inputs`` (on the same samples) at lags up to :data:`LAGS`, each at least ``level``; a
    test below ``level`` fails only where the largest squared correlation it rests on (the share of
    the residual's mean square one lagged copy of the residual or of an input predicts) is
    :func:`relevant` against ``target_rms``. ``failed`` names the checks missed."""
    r = residual.double().cpu()
    n = r.numel()
    lags = max(1, min(LAGS, n // 5))
    out = {"ljung_box_p": ljung_box(r, lags),
           "input_correlation_p": None, "failed": []}
    z = (r - r.mean()) / r.std().clamp_min(torch.finfo(r.dtype).tiny)
    correlation = lambda a, b: float((a * b).mean())
    autocorrelation = max(correlation(z[lag:], z[:n - lag]) ** 2 for lag in range(1, lags + 1))
    largest, cross, tests = 0.0, 0.0, 0
    for u in inputs:
        u = u.double().cpu()
        if float(u.std()) == 0.0:
            continue
        u = (u - u.mean()) / u.std()
        for lag in range(-lags, lags + 1):
            a, b = (z[lag:], u[:n - lag]) if lag >= 0 else (z[:n + lag], u[-lag:])
            c = correlation(a, b)
            largest, cross = max(largest, abs(c) * math.sqrt(a.numel())), max(cross, c**2)
            tests += 1
    if tests:
        out["input_correlation_p"] = float(min(1.0, tests * 2 * torch.special.ndtr(torch.tensor(-largest, dtype=torch.float64))))
    out["shares"] = {"autocorrelation": autocorrelation, "input_correlation": cross if tests else None}
    matters = lambda share: relevant(share, float(r.square().mean().sqrt()), target_rms, relative, absolute)
    if out["ljung_box_p"] < level and matters(autocorrelation):
        out["failed"].append(f"the re-fitted start's residual is autocorrelated (Ljung-Box p = {out['ljung_box_p']:.2g}; "
                             f"one lag predicts {100 * autocorrelation:.0f} % of its mean square)")
    if out["input_correlation_p"] is not None and out["input_correlation_p"] < level and matters(cross):
        out["failed"].append(f"the re-fitted start's residual is correlated with the inputs (p = {out['input_correlation_p']:.2g}; "
                             f"one lagged input predicts {100 * cross:.0f} % of its mean square)")
    return out


def ljung_box(residual: torch.Tensor, lags: int) -> float:
    """The Ljung-Box p-value of ``residual``'s autocorrelation at lags 1..``lags``: ``Q = n (n + 2)
    sum_k rho_k^2 / (n - k)`` against the chi-square distribution with ``lags`` degrees of freedom
    (``statsmodels.stats.diagnostic.acorr_ljungbox``'s)."""
    x = residual.double() - residual.double().mean()
    n = x.numel()
    rho = torch.stack([(x[k:] * x[:n - k]).sum() for k in range(1, lags + 1)]) / (x * x).sum()
    q = n * (n + 2) * float((rho**2 / (n - torch.arange(1, lags + 1, dtype=x.dtype))).sum())
    return chi2_sf(q, lags)


def chi2_sf(x: float, df: int) -> float:
    """The chi-square distribution's survival function, ``P(X > x)`` for ``df`` degrees of freedom:
    the regularised upper incomplete gamma function ``Q(df / 2, x / 2)``."""
    return float(torch.special.gammaincc(torch.tensor(df / 2, dtype=torch.float64), torch.tensor(x / 2, dtype=torch.float64)))


def nearest(points: torch.Tensor, queries: torch.Tensor, k: int) -> torch.Tensor:
    """The indices (Q, k) of the ``k`` points (N, D) nearest to each query (Q, D), nearest first, by
    Euclidean distance: up to :data:`BRUTE_FORCE` query-point pairs from every distance (exact
    differences; no scipy import, a fifth of a second of a short diagnosis), beyond by a k-d tree
    (``scipy.spatial.cKDTree``: n log n, not the Q x N distances)."""
    if queries.shape[0] * points.shape[0] <= BRUTE_FORCE:
        distances = torch.cdist(queries, points, compute_mode="donot_use_mm_for_euclid_dist")
        return distances.topk(k, largest=False).indices
    from scipy.spatial import cKDTree

    _, found = cKDTree(points.cpu().numpy()).query(queries.cpu().numpy(), k=list(range(1, k + 1)))
    return torch.as_tensor(found, device=points.device)
