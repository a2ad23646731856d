"""The records of an equation's diagnosis in ``gap_report.json``, typed: what each of
:class:`~msam_torch.diagnosis.report.gap_report.EquationGap`'s record fields holds. Every key is
optional (a record holds what its stage found); a number that is not finite is written as the
string ``"inf"``, ``"-inf"`` or ``"nan"`` (JSON has none). The JSON schema of the whole report is
:func:`msam_torch.diagnosis.report.json_schema.gap_report_schema`."""
from __future__ import annotations

from typing import Optional, Union

from typing_extensions import TypedDict  # pydantic reads its fields on Python < 3.12


class Confidence(TypedDict, total=False):
    """How sure the selection is (:mod:`msam_torch.diagnosis.compare.confidence`)."""

    margin: Optional[float]  # held-out RMSE of the best hypothesis with another name, relative
    runner_up: Optional[str]
    rival: Optional[str]  # the hypothesis hardest to tell apart on out-of-sample rows
    rival_equation: Optional[str]
    apart_p: Optional[float]
    apart_p_held_out: Optional[float]
    apart_p_training: Optional[float]
    win_frequency: Optional[float]  # share of the bootstrap trials the best hypothesis wins
    bootstrap_trials: int
    outcomes: dict[str, int]


class Improvement(TypedDict, total=False):
    """Held-out weak-form RMSE of the retuned and adapted models and the null rule applied."""

    retuned_rmse: Optional[float]
    adapted_rmse: Optional[float]
    relative: Optional[float]
    target_rms: Optional[float]
    rule: dict


class Where(TypedDict, total=False):
    """Where the gap lies (:mod:`msam_torch.diagnosis.stages.localise`)."""

    flagged_fraction: float
    time_windows: list
    regions: list
    split_explained: Optional[float]
    residual_rms: Optional[float]  # of the starting structure fitted to every one-step row
    target_rms: Optional[float]  # of the one-step rows' target
    held_out_explained: Optional[float]  # share of the held-out rows' squared residual the best split removes


class Estimator(TypedDict, total=False):
    """The weak form's test functions and the derivative estimator the rows were built with."""

    test_function: str
    half_width: Optional[float]
    half_width_samples: Optional[float]
    half_width_rule: str
    band_edge: Optional[float]
    band_edges: dict
    derivatives: dict
    derivative_cutoff: Optional[float]
    decimation: int
    refinement: int
    rows: int
    weak_form_signals: str
    input_hold: dict
    held_out_input_hold: dict
    kinks_corrected: list


class Checks(TypedDict, total=False):
    """The residual checks behind "no significant gap", and the reasons one failed."""

    failed: list[str]
    reasons: list[str]
    negligible: bool  # the residual is within the null rule's absolute margin
    unchecked: Optional[str]
    independent_rows: Optional[int]
    noise_p: Optional[float]
    ljung_box_p: Optional[float]
    input_correlation_p: Optional[float]
    structure_share: Optional[float]


class Naming(TypedDict, total=False):
    """How the best hypothesis reads in the catalogue (:mod:`msam_torch.diagnosis.catalogue.naming`)."""

    text: str
    effect: Optional[str]
    total_exponent: Optional[float]
    half_width: Optional[float]
    on: Optional[str]
    catalogue_exponent: Union[float, list, None]
    consistent: list
    domain: Optional[str]
    description: Optional[str]
    reference: Optional[str]
    quantities: dict
    assumed_quantities: dict
    at_catalogue_exponent: Optional[str]


class InTurn(TypedDict, total=False):
    """Several effects in turn (:mod:`msam_torch.diagnosis.effects.multi`)."""

    effects: list[dict]
    stopped: str
    accepted_model: dict[str, str]  # per equation, the model with every accepted effect
    diagnoses: int
