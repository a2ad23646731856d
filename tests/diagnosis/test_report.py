"""The gap report's files: figures with titles, units and legends at >= 120 dpi, laid out without
clipped or overlapping text and with the record's edges shaded, residual correlations with their
white-noise band, the frequency response, parameter and exponent intervals, clean tables whose
hypotheses are told apart, a plain-language summary before the numbers, one self-contained HTML
file and the diagnosis in TensorBoard; on a withheld-effect case (quadratic drag) and, marked
slow, on the EMPS record."""
import math
import re
from dataclasses import replace
from functools import lru_cache
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from msam_torch.cli.main import main
from msam_torch.diagnosis import Verdict, diagnose
from msam_torch.diagnosis.report.document import HYPOTHESES, interval_text, margin, markdown
from msam_torch.diagnosis.report.edges import Edges, edges
from msam_torch.diagnosis.report.figures import DPI, correlations, draw, render
from msam_torch.diagnosis.report.html import page
from msam_torch.diagnosis.report.summary import paragraph
from msam_torch.diagnosis.report.units import Units
from tests.diagnosis.test_diagnose import FAST, case_data
from tests.helpers import CONFIGS

UNITS = {"x": {"quantity": "position", "unit": "m"}, "x_dot": "velocity", "u": {"quantity": "force", "unit": "N"}}
FIGURES = {"x_ddot_residual_time.png", "x_ddot_residual_vs_state.png", "x_ddot_residual_correlation.png",
           "free_run_train.png", "free_run_held_out.png", "frequency_response_train.png",
           "frequency_response_held_out.png"}


@lru_cache(maxsize=None)
def drag_report():
    w, (train, held_out) = case_data("msd_quadratic_drag", noise=0.005)
    config = {"model": {**w.model, "quantities": UNITS}}
    return diagnose(config, data=train, validation=held_out, options=FAST)


def tables(text: str) -> list[list[str]]:
    """The body rows of every Markdown table in ``text``."""
    found, rows = [], []
    for line in text.splitlines() + [""]:
        if line.startswith("|"):
            rows.append(line)
        elif rows:
            found.append(rows[2:])
            rows = []
    return found


def png_width(png: bytes) -> int:
    return int.from_bytes(png[16:20], "big")  # the IHDR chunk's width


@pytest.mark.slow
def test_the_report_renders_self_contained_html_with_titled_figures(tmp_path):
    report = drag_report()
    assert report.verdict_kind is Verdict.EXPLAINED and report.equations[0].effect == "quadratic drag"
    report.save(tmp_path / "out", tensorboard=True)
    out = tmp_path / "out"
    assert {p.name for p in out.glob("*.png")} == FIGURES
    html = (out / "report.html").read_text()
    assert "http" not in html and "<script" not in html and "<link" not in html and "url(" not in html
    sources = re.findall(r'src="([^"]*)"', html)
    assert len(sources) == len(FIGURES) and all(s.startswith("data:image/png;base64,") for s in sources)
    text = (out / "report.md").read_text()
    for title in ("x_ddot: whiteness of the free-run error of x (held-out record)",
                  "Frequency response on the held-out record: data and free runs (Welch estimate)",
                  "Free runs on the train record: measured and simulated"):
        assert f"![{title}](" in text and f'alt="{title}"' in html
    assert "<table>" in html and "Residual checks" in html and "Parameters of the adapted model" in html
    for figure in render(report, Units(report.config)):  # 8 inches or more wide at DPI
        assert DPI >= 120 and png_width(figure.png) >= 4 * DPI and figure.title


def test_axis_labels_carry_the_declared_units():
    units = Units(drag_report().config)
    assert units.label("x") == "x [m]" and units.label("u") == "u [N]"
    assert units.label("x_ddot") == "x_ddot [m per time unit²]"
    assert units.label("x_dot") == "x_dot [m per time unit]"
    assert units.ratio("x", "u") == "|x / u| [m/N]"
    measured = Units({"model": {}, "data": {"time": "t_s", "columns": {"q": "qm_m", "tau": "force_N"}}})
    assert measured.label("q_dot") == "q_dot (d1/dt1 of column qm_m)" and measured.label("tau") == "tau (column force_N)"
    assert measured.time == "time (column t_s)"
    assert Units({"model": {"quantities": {"h": {"quantity": "level", "unit": None}}}}).label("h_dot") == (
        "h_dot (rate of level, unit not declared)")
    timed = Units({"model": {"quantities": {"x": {"quantity": "position", "unit": "m"}}},
                   "data": {"time": "t_s", "time_unit": "s"}})  # data.time_unit names the time column's unit
    assert timed.time == "time [s]" and timed.label("x_ddot") == "x_ddot [m per s²]" and timed.times == "s"
    assert timed.frequency() == "frequency (cycles per s)" and units.frequency() == "frequency (cycles per time unit)"


def test_the_record_edges_are_shaded_and_left_out_of_the_residual_axis():
    """Spikes of the derivative estimate at both ends of the record (half the savgol window: 7
    samples) are shaded and clipped; nothing flagged: no 'flagged' legend entry; a residual that is
    not finite somewhere is drawn (it raised "Axis limits cannot be NaN or Inf")."""
    import matplotlib.pyplot as plt

    t = torch.linspace(0.0, 10.0, 251, dtype=torch.float64)
    r = torch.sin(t)
    r[:4], r[-4:], r[100] = 50.0, -50.0, float("nan")  # NaN: a diverged fit's residual is not scaled
    where = {"t": t, "residual": r, "flagged": torch.zeros(251, dtype=torch.bool), "values": {"x": torch.cos(t)}}
    estimator = {"derivatives": {"x": {"method": "savgol", "window": 15}}, "refinement": 1}
    report = SimpleNamespace(series={"x_ddot": {"where": where}},
                             equations=[SimpleNamespace(target="x_ddot", estimator=estimator)])
    (_, _, over_time), (_, _, against) = draw(report, Units({"data": {"time_unit": "s"}}))
    for fig in (over_time, against):
        low, high = fig.axes[0].get_ylim()
        assert -1.2 < low < -0.99 and 0.99 < high < 1.2  # the sine, not the spikes
        labels = [text.get_text().replace("\n", " ") for text in fig.legends[0].get_texts()]
        assert not any("flagged" in label for label in labels) and clashes(fig) == []
        plt.close(fig)
    assert "record edges: derivative estimate unreliable (half the savgol window, 7 samples = 0.28 s; clipped)" in [
        text.get_text().replace("\n", " ") for text in over_time.legends[0].get_texts()]
    assert edges({"derivatives": {"x": {"method": "butterworth", "cutoff": 2.0}}}, "x_ddot", t.numpy()) == Edges(
        0.5, "a period at the butterworth cut-off, 0.5 time units")
    assert edges({"derivatives": "given"}, "x_ddot", t.numpy()) is None


def shown_ticks(ax) -> list:
    """The tick labels an axes draws: visible, with text, at a tick inside its view limits."""
    labels = []
    for axis, limits in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
        low, high = sorted(limits)
        slack = 1e-9 * (high - low)
        labels += [label for tick in axis.get_major_ticks() + axis.get_minor_ticks()
                   if low - slack <= tick.get_loc() <= high + slack
                   for label in (tick.label1, tick.label2) if label.get_visible() and label.get_text().strip()]
    return labels


def clashes(fig) -> list[str]:
    """What breaks the layout of a drawn figure: a text (title, label, tick label, legend) reaching
    outside the canvas; a title, axis label or tick label overlapping another axes' or the figure's
    title; a legend over an axes' data area."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = lambda artist: artist.get_window_extent(renderer)
    owned = [(None, t) for t in [fig._suptitle, *fig.texts] if t is not None and t.get_text().strip()]
    owned += [(ax, t) for ax in fig.axes for t in (ax.title, ax.xaxis.label, ax.yaxis.label) if t.get_text().strip()]
    owned += [(ax, t) for ax in fig.axes for t in shown_ticks(ax)]
    legends = fig.legends + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    canvas = fig.bbox.padded(1)  # a pixel of rounding
    named = [(repr(t.get_text()), t) for _, t in owned] + [("a legend", legend) for legend in legends]
    found = [f"{name} outside the canvas" for name, artist in named
             if not (canvas.contains(*box(artist).min) and canvas.contains(*box(artist).max))]
    for k, (ax, a) in enumerate(owned):
        found += [f"{a.get_text()!r} overlaps {b.get_text()!r}" for other, b in owned[k + 1:]
                  if other is not ax and box(a).overlaps(box(b))]
    found += [f"a legend over the data of {ax.get_title() or ax.get_ylabel()!r}" for legend in legends
              for ax in fig.axes if box(legend).overlaps(box(ax).shrunk(1, 1))]
    return found


@pytest.mark.parametrize("quantities", [None, {s: {"quantity": q} for s, q in (("x", "position"), ("x_dot", "velocity"),
                                                                              ("u", "force"))}])
def test_every_figure_renders_without_clipped_or_overlapping_text(quantities):
    """At the default size, with short (declared units) and long (quantities without units) labels."""
    import matplotlib.pyplot as plt

    report = drag_report()
    drawn = draw(report, Units(report.config if quantities is None else {"model": {"quantities": quantities}}))
    assert {f"{name}.png" for name, _, _ in drawn} == FIGURES
    found = {}
    for name, _, fig in drawn:
        found[name] = clashes(fig)
        plt.close(fig)
    assert found == {name: [] for name, _, _ in drawn}


def test_correlation_band_and_values_match_a_direct_computation():
    rng = np.random.default_rng(0)
    u = rng.standard_normal(800)
    r = 0.5 * np.roll(u, 3) + rng.standard_normal(800)
    found = correlations(r, {"u": u, "constant": np.ones(800)}, lags=10)
    assert found["band"] == pytest.approx(1.96 / math.sqrt(800), rel=1e-12) and found["n"] == 800
    z = r - r.mean()
    direct = [float((z[k:] * z[:800 - k]).sum() / (z * z).sum()) for k in range(11)]
    np.testing.assert_allclose(found["acf"], direct, atol=1e-10)
    a, b = (r - r.mean()) / r.std(), (u - u.mean()) / u.std()
    cross = {k: float((a[k:] * b[:800 - k]).sum() / 800) if k >= 0 else float((a[:800 + k] * b[-k:]).sum() / 800)
             for k in range(-10, 11)}
    np.testing.assert_allclose(found["ccf"]["u"], [cross[k] for k in range(-10, 11)], atol=1e-10)
    assert int(np.argmax(found["ccf"]["u"])) == 10 + 3  # the residual follows the input by 3 samples
    assert found["ccf"]["u"][13] == pytest.approx(0.5 / math.sqrt(1.25), abs=0.03) and abs(found["ccf"]["u"][5]) < found["band"] and "constant" not in found["ccf"]
    assert found["lags"] == 10 and correlations(r[:20], {}, lags=10)["lags"] == 5  # at most a quarter


def test_parameter_and_exponent_intervals_hold_the_true_drag():
    gap = drag_report().equations[0]
    terms = {t["term"].split("|")[0] if "|" in t["term"] else t["term"]: t for t in gap.intervals}
    drag = next(t for t in gap.intervals if t["exponent"] is not None)
    assert drag["term"].startswith("x_dot|x_dot|^")
    assert drag["theta"] == pytest.approx(-0.4, abs=0.02) and drag["exponent"] == pytest.approx(1.0, abs=0.02)
    low, high = drag["theta_interval"]
    assert low < high and high - low < 0.1 and low <= -0.4 + 0.01 and high >= -0.4 - 0.01
    assert drag["exponent_interval"][0] <= 1.0 + 0.01 <= drag["exponent_interval"][1] + 0.02
    assert terms["x"]["theta"] == pytest.approx(-4.0, abs=0.05) and terms["u"]["theta"] == pytest.approx(1.0, abs=0.02)
    assert terms["u"]["exponent"] is None and terms["u"]["exponent_interval"] is None


def test_tables_have_no_duplicated_rows_and_no_zero_length_windows():
    report = drag_report()
    gap = report.equations[0]
    windows = [{"start": 0.0, "stop": 0.0, "energy_share": 0.0}, {"start": 2.0, "stop": 3.5, "energy_share": 0.6},
               {"start": 2.0, "stop": 3.5, "energy_share": 0.6}, {"start": 4.25, "stop": 4.25, "energy_share": 0.004}]
    noisy = replace(gap, where={**gap.where, "time_windows": windows}, ranking=gap.ranking + gap.ranking[:3])
    text = markdown(replace(report, equations=(noisy,)), [])
    for rows in tables(text):
        assert len(rows) == len(set(rows)), rows
    assert "0 .. 0" not in text and "4.25 .. 4.25" not in text and "| 2 .. 3.5 | 60 % |" in text
    assert "2 isolated flagged samples (no window; 0.4 % of the residual energy) are not listed." in text
    hypotheses = [r for r in tables(text) if r and r[0].startswith(f"| `{gap.ranking[0]['hypothesis']}`")]
    assert hypotheses and len(hypotheses[0]) == len({r for r in hypotheses[0]})


def test_hypotheses_of_one_form_are_told_apart_by_their_start():
    """The three starts of an additive form (ADDITIVE_STARTS) printed the same hypothesis text
    three times; each row now says its kind and the start its fit began at."""
    report = drag_report()
    gap = report.equations[0]
    assert sorted({r["start"] for r in gap.ranking if r["kind"] == "additive"}) == [-0.5, 0.5, 1.5]
    assert all(r["start"] is None for r in gap.ranking if r["kind"] != "additive")
    text = markdown(replace(report, equations=(replace(gap, ranking=gap.ranking[:HYPOTHESES]),)), [])
    rows = next(rows for rows in tables(text) if rows and rows[0].startswith(f"| `{gap.ranking[0]['hypothesis']}`"))
    told = [tuple(row.split(" | ")[:2]) for row in rows]  # hypothesis and kind
    assert len(rows) == len(set(told)) == min(len(gap.ranking), HYPOTHESES)
    best = gap.ranking[0]
    assert rows[0].startswith(f"| `{best['hypothesis']}` | additive, from gamma = {best['start']:g} | quadratic drag |")


def test_the_summary_reads_in_plain_language_before_the_numbers():
    """What is missing, where, how much better on held-out data, how sure; gamma and the total
    exponent each said once, with what each is."""
    report = drag_report()
    gap = report.equations[0]
    naming, c = gap.naming, gap.confidence
    printed = str(report)
    lines = printed.splitlines()
    assert lines[1] == "summary:" and lines[2].startswith("  x_ddot: the starting model misses quadratic drag (")
    assert lines[3] == "numbers:" and lines[4] == "x_ddot: gap explained by quadratic drag"
    assert (f"with gamma = {gap.exponent:.3f}: the added term varies as |x_dot|^{naming['total_exponent']:.2f} ± "
            f"{naming['half_width']:.2f} (gamma plus the power of x_dot in the term it multiplies: the total "
            f"exponent the catalogue compares; quadratic drag: {gap.catalogue_exponent})") in lines[2]
    assert (f"On held-out data the adapted model's error (RMSE of x_ddot) is {100 * gap.improvement['relative']:.0f} % "
            "lower than that of the starting model with its parameters re-fitted.") in lines[2]
    assert f"How sure: it is the best fit in {100 * c['win_frequency']:.0f} % of {c['bootstrap_trials']} " in lines[2]
    assert f"gamma {gap.exponent:.3f}; quadratic drag (mechanical): total exponent" in printed  # the numbers, labelled
    text = markdown(report, [])
    assert text.index("## Summary") < text.index(lines[2].strip()) < text.index("## x_ddot")
    quiet = replace(gap, significant=False, verdict_kind=Verdict.NO_GAP, effect=None)
    assert paragraph(quiet).startswith("x_ddot: nothing is missing that the data show.")


def test_an_interval_wider_than_its_value_says_so():
    assert interval_text(-0.84, 1.87, 0.46, 100, " %") == "-84 to 187 %: not determined by these data"
    assert interval_text(0.12, 0.25, 0.13, 100, " %") == "12 to 25 %"
    assert interval_text(-0.4069, -0.3486, -0.4036) == "-0.4069 to -0.3486"


def test_html_embeds_only_the_figures_it_is_given():
    from msam_torch.diagnosis.report.figures import Figure

    text = "# T\n\n![a plot](a.png)\n\n| x | y |\n|---|---|\n| 1 | `\\|x\\| > 1` |\n"
    html = page(text, [Figure("a.png", "a plot", b"\x89PNG")])
    assert 'src="data:image/png;base64,iVBORw==' in html and "<td>1</td>" in html and "<title>" in html
    assert "<td><code>|x| &gt; 1</code></td>" in html


def test_tensorboard_holds_the_diagnosis_and_its_figures(tmp_path):
    report = drag_report()
    report.save(tmp_path, tensorboard=True)
    events = EventAccumulator(str(tmp_path / "tensorboard"), size_guidance={"images": 0, "scalars": 0, "tensors": 0})
    events.Reload()
    images = set(events.Tags()["images"])
    assert images == {f"diagnosis/{name.removesuffix('.png')}" for name in FIGURES}
    image = events.Images("diagnosis/frequency_response_held_out")[0]
    assert image.width >= 4 * DPI and image.height > 100
    exponent = events.Scalars("diagnosis/x_ddot/exponent")[0].value
    assert exponent == pytest.approx(report.equations[0].exponent, abs=1e-6)
    nrmse = events.Scalars("diagnosis/free_run_nrmse/held_out/adapted")[0].value
    assert nrmse == pytest.approx(report.measures["free_run"]["held_out"]["nrmse"]["adapted"], rel=1e-6)
    summary = events.Tensors("diagnosis/summary/text_summary")[0].tensor_proto.string_val[0].decode()
    assert "gap explained by quadratic drag" in summary
    report.save(tmp_path)  # a report folder with its event files is replaced as a whole
    assert not (tmp_path / "tensorboard").exists() and (tmp_path / "report.html").is_file()


@pytest.mark.slow
def test_the_emps_report_renders_with_every_figure(tmp_path, capsys):
    assert main(["diagnose", str(CONFIGS / "emps.yaml"), "--out", str(tmp_path), "--quiet", "--no-tensorboard"]) == 0
    names = {p.name for p in tmp_path.glob("*.png")}
    assert names == {n.replace("x_ddot", "q_ddot") for n in FIGURES}
    html = (tmp_path / "report.html").read_text()
    assert html.count('src="data:image/png;base64,') == len(FIGURES) and "http" not in html
    text = (tmp_path / "report.md").read_text()
    assert "| `q_dot` (copy 2) |" in text  # the viscous term's two copies (configs/emps.yaml) each with its row
    assert "| model | N | L | band | autocorrelation outside | correlation with tau outside |" in text
    for rows in tables(text):
        assert len(rows) == len(set(rows)), rows
    assert "report.html" in capsys.readouterr().out


@pytest.mark.slow
def test_msam_diagnose_writes_the_html_and_tensorboard_and_replaces_them_as_one_set(tmp_path, capsys):
    out = tmp_path / "out"
    for _ in range(2):  # the second run replaces the first set, event files included
        assert main(["diagnose", str(CONFIGS / "msd_coulomb.yaml"), "--out", str(out), "-q", "--bootstrap", "2"]) == 0
    assert len(list((out / "tensorboard").glob("events.out.tfevents.*"))) == 1
    assert (out / "report.html").is_file() and f"{out / 'report.html'}" in capsys.readouterr().out
    assert main(["diagnose", str(CONFIGS / "msd_coulomb.yaml"), "--out", str(tmp_path / "bare"), "-q",
                 "--bootstrap", "2", "--no-tensorboard", "--no-plots"]) == 0
    assert sorted(p.name for p in (tmp_path / "bare").iterdir()) == ["gap_report.json", "report.html", "report.md"]


def test_the_margin_names_the_rival_even_without_a_fitted_runner_up():
    """The margin counts effect hypotheses only; a rival held at a catalogue exponent is still
    reported when no fitted effect with another name is left (EMPS: the other fits are not
    admissible or repeat the winner's form)."""
    base = {"margin": 0.25, "runner_up": "power law, no catalogued effect", "rival": "power law, no catalogued effect",
            "apart_p_held_out": 0.02, "apart_p_training": 0.04}
    assert margin(base) == ("margin 25.0 % to power law, no catalogued effect, it as good in 2 % of held-out "
                            "resamples and within the margin in 4 % of cross-fitted training ones")
    pinned = {**base, "margin": math.inf, "runner_up": None, "rival": "quadratic drag at its catalogue exponent"}
    assert margin(pinned) == ("no other fitted effect with another name; quadratic drag at its catalogue exponent as "
                              "good in 2 % of held-out resamples and within the margin in 4 % of cross-fitted "
                              "training ones")
    assert margin({**pinned, "rival": None}) == "no competing hypothesis with another name"


def test_a_long_line_keeps_each_pixel_columns_first_lowest_highest_and_last_sample():
    from matplotlib.figure import Figure as Drawing

    from msam_torch.diagnosis.report.figures import columns

    fig = Drawing(figsize=(2, 1), dpi=100)  # 200 pixel columns
    t = np.linspace(0.0, 1.0, 20001)
    y = np.sin(40 * t) + np.random.default_rng(0).standard_normal(t.size)
    kept_t, kept_y = columns(t, y, fig)
    assert kept_t.size <= 4 * 200 and kept_t[0] == t[0] and kept_t[-1] == t[-1] and np.all(np.diff(kept_t) > 0)
    column = lambda x: np.minimum((x * 200).astype(int), 199)
    for c in (0, 57, 199):
        inside, kept = column(t) == c, column(kept_t) == c
        assert kept_y[kept].min() == y[inside].min() and kept_y[kept].max() == y[inside].max()
    assert columns(t[:800], y[:800], fig)[0].size == 800  # at most four samples a column: all kept
    y[5] = np.nan
    assert columns(t, y, fig)[0].size == t.size  # a line with a gap is drawn whole
