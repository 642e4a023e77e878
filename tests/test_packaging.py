"""Packaging and CI hygiene: the package installs without deprecation warnings on
current setuptools, and a hung test fails fast, with its name, instead of running into CI's
limit."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import tomllib

REPO = Path(__file__).resolve().parents[1]


def _pyproject() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text())


def test_license_is_an_spdx_string_with_a_setuptools_that_reads_it():
    """setuptools deprecates the TOML-table ``project.license`` (builds stop working after
    2027-02-18); the SPDX string form needs setuptools >= 77 (PEP 639)."""
    p = _pyproject()
    assert p["project"]["license"] == "BSD-3-Clause"
    assert "setuptools>=77" in " ".join(p["build-system"]["requires"]).replace(" ", "")


def test_a_hung_test_fails_fast_and_names_itself(tmp_path):
    """The suite's per-test timeout (pyproject ``timeout``, pytest-timeout) is active: a test
    that hangs is killed after the timeout and reported by name (here with the timeout
    lowered to 2 s for a 60 s sleep)."""
    assert _pyproject()["tool"]["pytest"]["ini_options"]["timeout"] > 0
    (tmp_path / "test_hang.py").write_text(
        textwrap.dedent("""
        import time

        def test_that_hangs():
            time.sleep(60)
    """)
    )
    start = time.monotonic()
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "-o",
            "timeout=2",
            str(tmp_path / "test_hang.py"),
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    elapsed = time.monotonic() - start
    assert proc.returncode != 0
    assert elapsed < 30.0, elapsed
    assert "test_that_hangs" in proc.stdout and "Timeout" in proc.stdout, proc.stdout[-2000:]


def test_the_readme_names_every_estimator_make_run_prints():
    """ "What `make run` does" names each estimator of the default scenario (the table it
    prints has one row per estimator)."""
    import re

    from drake_att.scenarios.library import load

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(root, "README.md"), encoding="utf-8") as f:
        text = f.read()
    section = text.split("## What `make run` does", 1)[1].split("\n## ", 1)[0]
    prose = section.split("\n|", 1)[0]  # the text before the table of files
    named = set(re.findall(r"`([a-z_0-9]+)`", prose))
    estimators = {e.name for e in load().estimators}
    assert estimators <= named, sorted(estimators - named)
    words = {2: "two", 3: "three", 4: "four", 5: "five", 6: "six"}
    assert f"{words[len(estimators)]} estimators" in " ".join(prose.split())
