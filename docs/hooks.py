"""MkDocs hooks of the documentation site (mkdocs.yml ``hooks``).

- The scenario-YAML reference page is ``docs/config_reference.md``, generated from the config
  dataclasses; the build fails when the committed file differs from what
  ``drake_att.scenarios.ranges.render_markdown`` renders now, so the site cannot show a stale one.
- The notebooks in ``notebooks/`` are the Tutorials pages (``tutorials/<name>.ipynb``), rendered by
  mkdocs-jupyter without running them.
- TeX math (``$...$``, ``$$...$$``, marked by ``pymdownx.arithmatex``) becomes MathML at build time:
  browsers draw MathML natively, so no math script is downloaded.
- nbconvert's page template adds MathJax and Mermaid from a CDN; the notebooks have neither math
  nor diagrams, so those script tags are dropped and the site loads nothing from the network.
"""

from __future__ import annotations

import html
import re
import sys
from pathlib import Path

from latex2mathml.converter import convert as latex_to_mathml
from mkdocs.exceptions import PluginError
from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

REPO = Path(__file__).resolve().parents[1]
CONFIG_REFERENCE = REPO / "docs" / "config_reference.md"
NOTEBOOKS = REPO / "notebooks"
TUTORIALS = "tutorials"
REGENERATE = "python -m drake_att.scenarios.ranges > docs/config_reference.md"


def on_pre_build(config) -> None:
    """Fail the build when the committed YAML reference is not what the config dataclasses give."""
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))  # this checkout's drake_att, not another installed one
    from drake_att.scenarios.ranges import render_markdown

    if CONFIG_REFERENCE.read_text(encoding="utf-8") != render_markdown():
        raise PluginError(f"{CONFIG_REFERENCE} is stale; regenerate it with `{REGENERATE}`")


@event_priority(100)  # before mkdocs-jupyter's on_files, which turns .ipynb files into pages
def on_files(files, config):
    """Add notebooks/*.ipynb as tutorials/<name>.ipynb."""
    for notebook in sorted(NOTEBOOKS.glob("*.ipynb")):
        files.append(File.generated(config, f"{TUTORIALS}/{notebook.name}", abs_src_path=str(notebook)))
    return files


def on_nav(nav, config, files):
    """mkdocs-jupyter wraps each notebook in a file object of its own that looks its source up under
    the docs folder; point the wrapped tutorials back at notebooks/ (before any page is read)."""
    for file in files:
        if file.src_uri.startswith(f"{TUTORIALS}/") and file.src_uri.endswith(".ipynb"):
            file.__dict__["abs_src_path"] = str(NOTEBOOKS / file.src_uri.split("/", 1)[1])
    return nav


_INLINE_MATH = re.compile(r'<span class="arithmatex">\\\((.*?)\\\)</span>', re.DOTALL)
_BLOCK_MATH = re.compile(r'<div class="arithmatex">\\\[(.*?)\\\]</div>', re.DOTALL)


def _mathml(tex: str, display: str, page) -> str:
    try:
        return latex_to_mathml(html.unescape(tex).strip(), display=display)
    except Exception as exc:  # noqa: BLE001 - any parser failure is a build error naming the formula
        raise PluginError(f"{page.file.src_uri}: cannot convert the formula {tex[:80]!r} to MathML: {exc}") from exc


def on_page_content(content: str, page, config, files) -> str:
    """TeX marked by arithmatex -> MathML (inline and display)."""
    content = _BLOCK_MATH.sub(lambda m: _mathml(m.group(1), "block", page), content)
    return _INLINE_MATH.sub(lambda m: _mathml(m.group(1), "inline", page), content)


_REMOTE_SCRIPT = re.compile(r'<script[^>]*\bsrc="https?://[^"]*"[^>]*>\s*</script>', re.IGNORECASE)


def on_post_page(output: str, page, config) -> str:
    """Drop the CDN scripts nbconvert's template puts on notebook pages (nothing on them uses them)."""
    if page.file.src_uri.endswith(".ipynb"):
        output = _REMOTE_SCRIPT.sub("", output)
    return output
