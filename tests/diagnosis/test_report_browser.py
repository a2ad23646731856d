"""The HTML report as a browser shows it: headless Chromium renders ``report.html`` to a screenshot
of the window's size, neither blank nor missing its figures (their plot colours among the pixels,
absent when the figures do not load). Skipped where no ``chromium`` is installed, unless
``MSAM_REQUIRE_BROWSER=1`` (CI installs it and sets that), where that fails."""
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from tests.diagnosis.test_report import FIGURES, drag_report

WIDTH, HEIGHT = 1280, 2000  # the first figure lies within this height of the page
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
PLOTTED = (31, 119, 180)  # matplotlib's tab:blue, the residual's line (the page's style has no blue)


def chromium() -> str:
    found = shutil.which("chromium")
    if found is None:
        if os.environ.get("MSAM_REQUIRE_BROWSER") == "1":
            pytest.fail("MSAM_REQUIRE_BROWSER=1 and no chromium on the PATH")
        pytest.skip("no chromium on the PATH (MSAM_REQUIRE_BROWSER=1 makes this a failure)")
    return found


def screenshot(browser: str, page: Path, folder: Path) -> np.ndarray:
    """RGB values 0-255 (HEIGHT, WIDTH, 3) of ``page`` as headless Chromium (``browser``) shows it."""
    shot = folder / f"{page.stem}.png"
    done = subprocess.run([browser, *FLAGS, f"--user-data-dir={folder / 'profile'}", f"--screenshot={shot}",
                           f"--window-size={WIDTH},{HEIGHT}", page.as_uri()],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0 and shot.is_file(), done.stderr[-2000:]
    return (imread(shot)[..., :3] * 255).round().astype(int)


def plotted(pixels: np.ndarray) -> int:
    """How many pixels hold the plots' blue."""
    return int((np.abs(pixels - PLOTTED) <= 8).all(-1).sum())


@pytest.mark.slow
def test_the_html_report_renders_in_a_headless_browser_with_its_figures(tmp_path):
    browser = chromium()
    drag_report().save(tmp_path / "out", plots=True)
    page = tmp_path / "out" / "report.html"
    html = page.read_text()
    assert html.count('src="data:image/png;base64,') == len(FIGURES)
    pixels = screenshot(browser, page, tmp_path)
    assert pixels.shape == (HEIGHT, WIDTH, 3)
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 200  # text, tables and figures: not blank
    assert plotted(pixels) > 500  # the first figures loaded
    broken = tmp_path / "broken.html"  # the same page, its figures not found: the check tells them apart
    broken.write_text(html.replace('src="data:image/png;base64,', 'src="missing.png#'))
    assert plotted(screenshot(browser, broken, tmp_path)) == 0
