"""Griffe extension of the API reference (mkdocs.yml): the docstrings are written with two pieces
of reStructuredText that Markdown would print literally, so each docstring is rewritten first:

- simple tables (columns framed by ``====  ====`` lines; a row whose first cell is blank continues
  the row above) become Markdown tables;
- cross-reference roles (``:class:`X```, ``:func:`~a.b```) become code spans of the name (``~``
  keeps only its last component, as in Sphinx).
"""

from __future__ import annotations

import re

import griffe

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|exc|obj|const|term):`(~?)([^`]+)`")
_BORDER = re.compile(r"^(\s*)=+(?:\s+=+)+\s*$")


def _code_span(match: re.Match) -> str:
    short, name = match.group(1), match.group(2)
    return f"`{name.rsplit('.', 1)[-1] if short else name}`"


def _columns(border: str) -> list[tuple[int, int]]:
    return [(m.start(), m.end()) for m in re.finditer(r"=+", border)]


def _cells(line: str, columns: list[tuple[int, int]]) -> list[str]:
    starts = [start for start, _ in columns] + [None]
    return [line[starts[i] : starts[i + 1]].strip() for i in range(len(columns))]


def _markdown_row(cells: list[str]) -> str:
    return "| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |"


def _next_border(lines: list[str], start: int) -> int | None:
    return next((j for j in range(start, len(lines)) if _BORDER.match(lines[j])), None)


def _simple_tables_to_markdown(text: str) -> str:
    """Tables with a header (border, header lines, border, rows, border) and without (border,
    rows, border): a second border after one or two lines that is followed by rows is a header's."""
    lines, out, i = text.split("\n"), [], 0
    while i < len(lines):
        second = _next_border(lines, i + 1) if _BORDER.match(lines[i]) else None
        if second is None:
            out.append(lines[i])
            i += 1
            continue
        top, columns, indent = i, _columns(lines[i]), _BORDER.match(lines[i]).group(1)
        has_header = second - top <= 3 and second + 1 < len(lines) and lines[second + 1].strip() != ""
        bottom = _next_border(lines, second + 1) if has_header else second
        if bottom is None:
            out.append(lines[i])
            i += 1
            continue
        header_lines = lines[top + 1 : second] if has_header else [""]
        rows: list[list[str]] = []
        for line in lines[(second if has_header else top) + 1 : bottom]:
            if not line.strip():
                continue
            cells = _cells(line, columns)
            if rows and not cells[0]:
                rows[-1] = [f"{a} {b}".strip() for a, b in zip(rows[-1], cells, strict=True)]
            else:
                rows.append(cells)
        header = [" ".join(c).strip() for c in zip(*(_cells(h, columns) for h in header_lines), strict=True)]
        table = [_markdown_row(header), "| " + " | ".join("---" for _ in columns) + " |"]
        out += ["", *(indent + row for row in table + [_markdown_row(r) for r in rows]), ""]
        i = bottom + 1
    return "\n".join(out)


class RstToMarkdown(griffe.Extension):
    """Rewrite reStructuredText roles and simple tables in every docstring as Markdown."""

    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            text = _simple_tables_to_markdown(obj.docstring.value)  # first: the roles' rewrite moves columns
            obj.docstring.value = _ROLE.sub(_code_span, text)
