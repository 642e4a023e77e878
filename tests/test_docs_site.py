"""The documentation site (mkdocs.yml, docs/): it builds in strict mode (no warning, no broken
link or anchor), loads nothing from the network, and renders in a real browser without console
errors, its contract API page listing ``FilterCore`` and every registered plug-in config.

With ``DRAKE_ATT_DOCS_SCREENSHOTS=<folder>`` the browser test also writes its three screenshots
(start page, YAML reference, a paper page) there: ``docs/screenshots`` holds the committed ones.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from drake_att.analysis import campaign_report
from drake_att.analysis.campaign_report import find_chromium
from drake_att.scenarios import registry

REPO = Path(__file__).resolve().parents[1]
CHROMIUM = find_chromium()
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="no Chromium on PATH (Debian: apt-get install chromium; `make test` installs it as root)"
)
BUILD_ENV = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # mkdocs-material's banner about MkDocs 2.0


class _MkdocsLoader(yaml.SafeLoader):
    """mkdocs.yml as YAML: ``!ENV [NAME, default]`` reads as its default."""


_MkdocsLoader.add_constructor("!ENV", lambda loader, node: loader.construct_sequence(node)[-1])


def _mkdocs_settings() -> dict:
    return yaml.load((REPO / "mkdocs.yml").read_text(), Loader=_MkdocsLoader)  # noqa: S506 - a safe loader


def _mkdocs_build(config: Path, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(config), "--site-dir", str(site)],
        cwd=config.parent,
        capture_output=True,
        text=True,
        env=BUILD_ENV,
        timeout=300,
        check=False,
    )


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    proc = _mkdocs_build(REPO / "mkdocs.yml", out)
    assert proc.returncode == 0, proc.stderr[-3000:]
    warnings = [line for line in proc.stderr.splitlines() if line.startswith(("WARNING", "ERROR"))]
    assert warnings == [], warnings
    return out


# ======================================================================================
# The build
# ======================================================================================
@pytest.mark.slow
def test_every_page_of_the_navigation_is_built(site):
    def pages(nav):
        for item in nav:
            value = next(iter(item.values())) if isinstance(item, dict) else item
            if isinstance(value, list):
                yield from pages(value)
            else:
                yield value

    nav = _mkdocs_settings()["nav"]
    sources = list(pages(nav))
    assert "config_reference.md" in sources and "api/contract.md" in sources
    assert {f"papers/s{i}.md" for i in range(5)} <= set(sources)
    assert {f"tutorials/{p.name}" for p in (REPO / "notebooks").glob("*.ipynb")} <= set(sources)
    for source in sources:
        html = site / re.sub(r"\.(md|ipynb)$", ".html", source)
        assert html.is_file(), source


@pytest.mark.slow
def test_the_site_loads_nothing_from_the_network(site):
    """No page or style sheet makes the browser fetch anything remote at load (scripts, style
    sheets, fonts, images, frames): links the reader may click are allowed."""
    fetched = re.compile(
        r"""<(?:script|img|iframe|source|audio|video|embed)\b[^>]*\bsrc\s*=\s*["']?((?:https?:)?//[^"'\s>]+)"""
        r"""|<link\b(?=[^>]*\brel\s*=\s*["']?(?:stylesheet|preload|preconnect|icon|modulepreload))[^>]*\bhref\s*=\s*["']?((?:https?:)?//[^"'\s>]+)"""
        r"""|@import\s+(?:url\()?["']?((?:https?:)?//[^"')\s]+)"""
        r"""|url\(\s*["']?((?:https?:)?//[^"')\s]+)""",
        re.IGNORECASE,
    )
    remote = {}
    files = list(site.rglob("*.html")) + list(site.rglob("*.css"))
    assert len(files) > 40
    for path in files:
        found = [next(g for g in m.groups() if g) for m in fetched.finditer(path.read_text(encoding="utf-8"))]
        if found:
            remote[str(path.relative_to(site))] = found[:3]
    assert remote == {}
    # The detector works: it finds the CDN scripts nbconvert's template puts on a notebook page.
    assert fetched.search('<script src="https://cdn.example.org/mathjax.js"></script>')
    assert fetched.search('<link rel="stylesheet" href="//fonts.example.org/css">')


@pytest.mark.slow
def test_math_is_mathml_and_the_notebooks_are_pages(site):
    page = (site / "derivations" / "mekf.html").read_text(encoding="utf-8")
    assert page.count("<math") > 10
    assert "arithmatex" not in page and "\\(" not in page
    tour = (site / "tutorials" / "tour.html").read_text(encoding="utf-8")
    assert "run_campaign" in tour or "drake_att" in tour


def test_a_broken_link_fails_the_strict_build(tmp_path):
    """The site's link validation settings make a broken link and a broken anchor a warning,
    which strict mode turns into a failed build (checked on a one-page site with the same settings)."""
    settings = _mkdocs_settings()
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "index.md").write_text("# Home\n\n## Section\n\n[fine](#section)\n")
    config = tmp_path / "mkdocs.yml"

    def build(page_text: str) -> subprocess.CompletedProcess:
        (docs / "index.md").write_text(page_text)
        config.write_text(
            yaml.safe_dump(
                {"site_name": "t", "strict": True, "validation": settings["validation"], "nav": ["index.md"]}
            )
        )
        return _mkdocs_build(config, tmp_path / "site")

    assert build("# Home\n\n## Section\n\n[fine](#section)\n").returncode == 0
    broken_link = build("# Home\n\n[gone](missing.md)\n")
    assert broken_link.returncode != 0 and "missing.md" in broken_link.stderr
    broken_anchor = build("# Home\n\n[gone](#no-such-section)\n")
    assert broken_anchor.returncode != 0 and "no-such-section" in broken_anchor.stderr


def test_a_stale_yaml_reference_fails_the_build(tmp_path, monkeypatch):
    """The reference page is docs/config_reference.md, generated from the config dataclasses:
    the build's hook refuses a committed file that differs from what the code renders."""
    from mkdocs.exceptions import PluginError

    spec = importlib.util.spec_from_file_location("docs_hooks", REPO / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    hooks.on_pre_build(None)  # the committed file is current
    stale = tmp_path / "config_reference.md"
    stale.write_text((REPO / "docs" / "config_reference.md").read_text().replace("deg/sqrt(h)", "deg/h", 1))
    monkeypatch.setattr(hooks, "CONFIG_REFERENCE", stale)
    with pytest.raises(PluginError, match=r"stale; regenerate it with `python -m drake_att.scenarios.ranges >"):
        hooks.on_pre_build(None)


# ======================================================================================
# In a browser
# ======================================================================================
def _chromium(page: Path, *extra: str) -> subprocess.CompletedProcess:
    """Headless Chromium on a built page; scripts get 5 s of virtual time to run first."""
    return campaign_report.run_headless_chromium(CHROMIUM, str(page), ["--virtual-time-budget=5000", *extra], 120)


def _console_errors(stderr: str) -> list[str]:
    """The page's console messages (Chromium logs them as ``CONSOLE`` lines) and uncaught errors."""
    return [line for line in stderr.splitlines() if ":CONSOLE" in line or "Uncaught" in line]


def _registered_plugin_configs() -> set[str]:
    return {p.config_type.__name__ for kind in ("estimator", "sensor") for p in registry.plugins(kind).values()}


@pytest.mark.slow
@needs_chromium
def test_start_page_and_contract_api_page_in_a_browser(site):
    for page in (site / "index.html", site / "api" / "contract.html"):
        proc = _chromium(page, "--dump-dom")
        assert proc.returncode == 0, proc.stderr[-1000:]
        assert _console_errors(proc.stderr) == [], (page.name, _console_errors(proc.stderr)[:3])
        dom = proc.stdout
        assert "drake_att" in dom and "</html>" in dom
    configs = _registered_plugin_configs()
    assert len(configs) >= 16 and {"MekfConfig", "GyroConfig"} <= configs
    # The API page, as the browser has it: the protocol and every registered plug-in config.
    assert re.search(r'id="drake_att\.contract\.FilterCore"', dom)
    missing = sorted(c for c in configs if f"<code>{c}</code>" not in dom)
    assert missing == [], missing
    # The detector works: a page with a script error is caught.
    broken = site / "broken.html"
    broken.write_text(
        (site / "index.html").read_text().replace("</body>", "<script>undefinedFunction();</script></body>")
    )
    assert any("undefinedFunction" in line for line in _console_errors(_chromium(broken, "--dump-dom").stderr))


@pytest.mark.slow
@needs_chromium
@pytest.mark.parametrize(
    ("page", "png"),
    [
        ("index.html", "start_page.png"),
        ("config_reference.html", "yaml_reference.png"),
        ("papers/s3.html", "paper_s3.png"),
    ],
)
def test_screenshots_of_the_start_page_the_yaml_reference_and_a_paper(site, tmp_path, page, png):
    shot = tmp_path / png
    proc = _chromium(site / page, f"--screenshot={shot}", "--window-size=1280,2000")
    assert proc.returncode == 0 and shot.is_file(), proc.stderr[-1000:]
    assert _console_errors(proc.stderr) == [], _console_errors(proc.stderr)[:3]
    from PIL import Image

    with Image.open(shot) as im:
        assert im.size == (1280, 2000)
        gray = np.asarray(im.convert("L"), dtype=float)
    assert gray.std() > 20 and (gray < 128).mean() > 0.01  # text and a header bar, not a blank page
    folder = os.environ.get("DRAKE_ATT_DOCS_SCREENSHOTS")
    if folder:
        os.makedirs(folder, exist_ok=True)
        shutil.copyfile(shot, os.path.join(folder, png))


# ======================================================================================
# The README
# ======================================================================================
def test_the_readme_is_a_page_whose_links_lead_into_the_docs():
    """At most 150 lines; every relative link names a file of the repository (so it works on
    GitHub as in a clone), and the site's main pages are among them."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 150
    targets = {m.split("#", 1)[0] for m in re.findall(r"\]\(([^)\s]+)\)", text) if not m.startswith("http")}
    missing = sorted(t for t in targets if not (REPO / t).exists())
    assert missing == [], missing
    assert {"docs/index.md", "docs/guide/cli.md", "docs/config_reference.md", "docs/papers/index.md"} <= targets
    assert "make docs" in text and "jupyter nbconvert --to notebook --execute" in text
