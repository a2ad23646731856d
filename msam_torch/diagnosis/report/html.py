"""The gap report as one self-contained HTML file: the Markdown document rendered by
Python-Markdown (tables extension), every figure embedded as a base64 PNG, the style inline; no
external file, script or font is referenced."""
from __future__ import annotations

import base64
import html

import markdown as markdown_lib

from msam_torch.diagnosis.report.figures import Figure

STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; max-width: 72rem; margin: 2rem auto;
       padding: 0 1rem; color: #222; line-height: 1.45; }
code { font-size: 0.9em; background: #f4f4f4; padding: 0 0.2em; }
table { border-collapse: collapse; margin: 0.6rem 0 1.2rem; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25rem 0.55rem; text-align: left; vertical-align: top; }
th { background: #f0f0f0; }
tr:nth-child(even) td { background: #fafafa; }
img { max-width: 100%; height: auto; display: block; margin: 0.5rem 0 1.5rem; }
"""


def page(text: str, figures: list[Figure], title: str = "Sim-to-real gap report") -> str:
    """``text`` (the report's Markdown) as an HTML page with ``figures`` (referenced in it by file
    name) embedded."""
    body = markdown_lib.markdown(text, extensions=["tables"], output_format="html")
    body = body.replace("\\|", "|")  # a table cell's escaped separator stays escaped inside code
    for figure in figures:
        data = base64.b64encode(figure.png).decode("ascii")
        body = body.replace(f'src="{figure.name}"', f'src="data:image/png;base64,{data}"')
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n<title>{html.escape(title)}</title>\n'
            f"<style>{STYLE}</style>\n</head>\n<body>\n{body}\n</body>\n</html>\n")
