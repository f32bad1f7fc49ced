"""report.html beside a report.md: the same text as one self-contained
page, its figures inlined as base64, readable in any browser and mailable
as one file."""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

# the source of an <img> that names a file (not a data: URI): stancal's
# reports write ![name](file.png), their figures beside report.md
_IMAGE = re.compile(r'(<img\b[^>]*\bsrc=")([^":]+)(")')
_TYPES = {".png": "image/png", ".svg": "image/svg+xml", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}
_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 60rem; margin: 2rem auto; padding: 0 1rem;
       line-height: 1.45; color: #222; }
table { border-collapse: collapse; margin: 1rem 0; font-size: 0.9rem; }
th, td { border: 1px solid #ccc; padding: 0.25rem 0.6rem; text-align: right; }
th:first-child, td:first-child { text-align: left; }
img { max-width: 100%; height: auto; display: block; margin: 1rem 0; }
code { background: #f4f4f4; padding: 0 0.2rem; }
"""


def _inline(match: re.Match, folder: Path) -> str:
    """An <img> of a figure beside the report, its source as a data URI."""
    path = folder / html.unescape(match.group(2))
    encoded = base64.b64encode(path.read_bytes()).decode("ascii")
    return f"{match.group(1)}data:{_TYPES.get(path.suffix.lower(), 'image/png')};base64,{encoded}{match.group(3)}"


def markdown_to_html(text: str, folder: Path, title: str) -> str:
    """A whole HTML page of the report's markdown (tables included), its
    figures read from ``folder`` and inlined."""
    import markdown  # Python-Markdown: tables as the reports write them (the tables extension)

    body = markdown.markdown(text, extensions=["tables"], output_format="html")
    body = _IMAGE.sub(lambda m: _inline(m, folder), body)
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f"<title>{html.escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n"
            f"<body>\n{body}\n</body>\n</html>\n")


def write_html(report: Path) -> Path:
    """report.html beside ``report`` (a report.md), with its figures inlined."""
    text = report.read_text()
    heading = next((line.lstrip("# ").strip() for line in text.splitlines() if line.startswith("#")), "report")
    target = report.with_suffix(".html")
    target.write_text(markdown_to_html(text, report.parent, heading))
    return target
