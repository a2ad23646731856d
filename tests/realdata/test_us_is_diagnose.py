"""The US IS model (paper Table 6) through ``msam diagnose``: the summary names the verdict and
the validation sum|eps| of the starting, theta re-fitted and adapted models."""
from dataclasses import replace
from pathlib import Path

from msam_torch.diagnosis import DiagnoseOptions, diagnose

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "us_is.yaml"


def test_us_is_diagnosis_prints_validation_sum_abs_error():
    report = diagnose(CONFIG, options=replace(DiagnoseOptions(), bootstrap=4, steps=20, free_run=False))
    held = report.measures["one_step"]["held_out"]["y_dot"]
    printed = str(report)
    assert printed.startswith(f"verdict: {report.verdict}")
    assert (f"one-step sum|eps| of y_dot against its estimate (held_out): start {held['start']['sum_abs_error']:.4g}, theta re-fitted "
            f"{held['retuned']['sum_abs_error']:.4g}, adapted {held['adapted']['sum_abs_error']:.4g}") in printed
    gap = report.equations[0]
    assert gap.start_equation == "y_dot = 0.1 (c + i + g) - 0.1 y"  # a sum is one factor
    assert "(c + i + g) -> (c + i + g)*abs(y)^gamma" in [h["hypothesis"] for h in gap.ranking]
    # re-fitting theta alone removes most of the starting model's one-step error on the held-out quarters
    assert held["retuned"]["sum_abs_error"] < 0.6 * held["start"]["sum_abs_error"]
    assert held["adapted"]["sum_abs_error"] <= held["retuned"]["sum_abs_error"]
