"""The tutorials' code runs as written, so the pages cannot go stale.

Each page of ``docs/tutorials/`` runs in a fresh folder (holding a link to the repository's
``configs/``), block by block in page order: a ``python`` block executes in one namespace per page,
a ``bash`` block runs each command in a shell (``# exits N`` at the end of a line expects that exit
status, else 0), a block with ``title="name"`` is written to that file. A ``text`` block right after
a ``python`` or ``bash`` block is its expected output: each of its lines must appear among the lines
printed, numbers within 2 % (or 1e-3). Pages that run shell commands (each a fresh process) are in
the slow tier."""
import contextlib
import io
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted((ROOT / "docs" / "tutorials").glob("*.md"))
FENCE = re.compile(r"^```(\w+)([^\n]*)\n(.*?)^```$", re.DOTALL | re.MULTILINE)
NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?%?$")
EXIT = re.compile(r"#\s*exits\s+(\d+)\s*$")


def blocks(page: Path) -> list[tuple[str, str, str]]:
    """(language, title or '', body) of every fenced block of a page, in order."""
    out = []
    for language, info, body in FENCE.findall(page.read_text()):
        title = re.search(r'title="([^"]+)"', info)
        out.append((language, title.group(1) if title else "", body))
    return out


def _same(expected: str, printed: str) -> bool:
    """The same tokens, numbers within 2 % (or 1e-3)."""
    a, b = expected.split(), printed.split()
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if NUMBER.match(x) and NUMBER.match(y):
            if not math.isclose(float(x.rstrip("%")), float(y.rstrip("%")), rel_tol=0.02, abs_tol=1e-3):
                return False
        elif x != y:
            return False
    return True


def check_output(expected: str, printed: str, where: str) -> None:
    lines = [line.strip() for line in printed.splitlines()]
    missing = [line for line in expected.strip().splitlines() if not any(_same(line, p) for p in lines)]
    assert not missing, f"{where}: expected output not printed: {missing}\n--- printed ---\n{printed}"


def run_page(page: Path, folder: Path) -> None:
    (folder / "configs").symlink_to(ROOT / "configs")
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    namespace: dict = {"__name__": "__tutorial__"}
    printed = None
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        for number, (language, title, body) in enumerate(blocks(page), 1):
            where = f"{page.name} block {number}"
            if title:
                (folder / title).write_text(body)
            elif language == "python":
                buffer = io.StringIO()
                with contextlib.redirect_stdout(buffer):
                    exec(compile(body, where, "exec"), namespace)  # noqa: S102 - the page's own code
                printed = buffer.getvalue()
                continue
            elif language == "bash":
                printed = ""
                for command in (c for c in body.splitlines() if c.strip() and not c.startswith("#")):
                    expected = int(EXIT.search(command).group(1)) if EXIT.search(command) else 0
                    done = subprocess.run(command, check=False, shell=True, cwd=folder, env=env, capture_output=True, text=True)
                    assert done.returncode == expected, f"{where}: {command!r} exit {done.returncode}\n{done.stderr}"
                    printed += done.stdout + done.stderr
                continue
            elif language == "text" and printed is not None:
                check_output(body, printed, where)
            printed = None
    finally:
        os.chdir(cwd)


def test_the_tutorials_are_found():
    assert {p.name for p in PAGES} >= {"own-system.md", "command-line.md", "reading-a-report.md"}
    assert all(any(lang in ("python", "bash") for lang, _, _ in blocks(p)) for p in PAGES)


@pytest.mark.parametrize("page", [
    pytest.param(p, marks=[pytest.mark.slow] * any(lang == "bash" for lang, _, _ in blocks(p))) for p in PAGES
], ids=lambda p: p.stem)
def test_tutorial_runs_as_written(page, tmp_path):
    run_page(page, tmp_path)


def test_a_wrong_output_is_caught(tmp_path):
    """The check is not vacuous: a page whose printed number differs by more than 2 % fails."""
    page = tmp_path / "page.md"
    page.write_text("```python\nprint('rate', 1.00)\n```\n\n```text\nrate 1.05\n```\n")
    work = tmp_path / "work"
    work.mkdir()
    with pytest.raises(AssertionError, match="expected output not printed"):
        run_page(page, work)
    page.write_text("```python\nprint('rate', 1.00)\n```\n\n```text\nrate 1.01\n```\n")
    (work / "configs").unlink()
    run_page(page, work)
