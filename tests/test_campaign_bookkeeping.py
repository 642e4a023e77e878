"""Bookkeeping users rely on without reading it: which default folder a command writes (a
modified run never replaces the unmodified one), and manifests that catch any edit of any
file, a same-size one too. Expectations are computed here from the definitions (SHA-1 of the
override strings, SHA-256 of each file), not with the library's helpers."""

from __future__ import annotations

import hashlib
import json
import os
import types

import pytest

from drake_att.analysis.montecarlo import check_campaign_manifest
from drake_att.analysis.report import check_manifest
from drake_att.cli import default_out


def _tag(items) -> str:
    return "_" + hashlib.sha1("\n".join(items).encode()).hexdigest()[:8] if items else ""


SCEN = types.SimpleNamespace(name="cubesat_single_star_tracker", seed=3)


def test_the_run_folder_names_the_scenario_the_seed_and_the_overrides():
    assert default_out("run", SCEN) == os.path.join("out", "cubesat_single_star_tracker_seed3")
    sets = ["duration_s=60", "sensors.st1.period_s=0.2"]
    assert default_out("run", SCEN, sets) == os.path.join("out", "cubesat_single_star_tracker_seed3" + _tag(sets))
    names = {
        default_out("run", SCEN, s)
        for s in (None, ["duration_s=60"], ["duration_s=61"], ["duration_s=60", "seed=2"], ["seed=2", "duration_s=60"])
    }
    assert len(names) == 5  # every change of an override, and of their order, is another folder
    other_seed = types.SimpleNamespace(name=SCEN.name, seed=4)
    assert default_out("run", other_seed) != default_out("run", SCEN)


def test_the_campaign_folder_changes_with_every_option_that_changes_its_runs():
    base = default_out("montecarlo", SCEN)
    assert base == os.path.join("out", "cubesat_single_star_tracker_montecarlo")
    with_set = default_out("montecarlo", SCEN, ["duration_s=60"])
    with_est = default_out("montecarlo", SCEN, None, "single")
    both = default_out("montecarlo", SCEN, ["duration_s=60"], "single")
    assert with_set == base + _tag(["duration_s=60"])
    assert with_est == base + _tag(["--estimators=single"])
    assert both == base + _tag(["duration_s=60", "--estimators=single"])
    assert len({base, with_set, with_est, both}) == 4
    # The seed of the scenario is not in it: a campaign's seeds come from --first-seed/--runs
    # and a campaign grows by --resume in its one folder.
    assert default_out("montecarlo", types.SimpleNamespace(name=SCEN.name, seed=9)) == base


def test_the_comparison_folder_changes_with_scenarios_overrides_and_estimators():
    a = default_out("compare", None, None, None, ["s1_cqe", "s4_lie_group"])
    assert a == os.path.join("out", "compare" + _tag(["s1_cqe", "s4_lie_group", ""]))
    variants = {
        a,
        default_out("compare", None, None, None, ["s4_lie_group", "s1_cqe"]),
        default_out("compare", None, ["duration_s=60"], None, ["s1_cqe", "s4_lie_group"]),
        default_out("compare", None, None, "mekf", ["s1_cqe", "s4_lie_group"]),
    }
    assert len(variants) == 4


def test_a_scenario_name_never_leaves_out():
    evil = types.SimpleNamespace(name="../../etc/x", seed=1)
    for command in ("run", "montecarlo"):
        path = default_out(command, evil)
        name = os.path.basename(path)
        assert os.path.dirname(path) == "out" and not name.startswith(".") and os.sep not in name
        assert os.path.normpath(path) == path


def _manifest(folder, names) -> None:
    """A manifest written here from its definition: name, size and SHA-256 of each file."""
    entries = []
    for n in names:
        data = (folder / n).read_bytes()
        entries.append({"file": n, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()})
    (folder / "manifest.json").write_text(
        json.dumps({"scenario": "s", "seed": 1, "runs": 1, "seeds": [1, 1], "files": entries})
    )


@pytest.mark.parametrize("check", [check_manifest, check_campaign_manifest], ids=["run", "campaign"])
def test_a_manifest_catches_a_same_size_edit_of_any_file(tmp_path, check):
    files = {"metrics.json": b'{"a": 1.25}', "config.yaml": b"name: x\n"}
    if check is check_campaign_manifest:  # a campaign's runs are in runs/ (a run folder has no sub-folder)
        (tmp_path / "runs").mkdir()
        files["runs/seed_1.npz"] = bytes(range(200))
    else:
        files["log.npz"] = bytes(range(200))
    for n, data in files.items():
        (tmp_path / n).write_bytes(data)
    _manifest(tmp_path, list(files))
    assert check(str(tmp_path)) == []
    for n, data in files.items():
        for i in (0, len(data) // 2, len(data) - 1):  # one byte changed, the size kept
            edited = bytearray(data)
            edited[i] ^= 0x01
            (tmp_path / n).write_bytes(bytes(edited))
            problems = check(str(tmp_path))
            assert any(p.startswith(n) for p in problems), (n, i, problems)
            (tmp_path / n).write_bytes(data)
    assert check(str(tmp_path)) == []
    (tmp_path / "config.yaml").unlink()
    assert any(p.startswith("config.yaml") and "missing" in p for p in check(str(tmp_path)))


def test_the_montecarlo_command_writes_an_estimator_selection_to_its_own_default_folder(tmp_path, monkeypatch):
    """Through the CLI, not only ``default_out``: a campaign of one estimator and the full
    campaign land in two folders, each named from its definition (a call site that dropped
    ``--estimators`` would make the second refuse the first's folder)."""
    from drake_att.cli import main as cli_main

    monkeypatch.chdir(tmp_path)
    short = ["duration_s=60", "scoring.score_from_s=20"]
    base = ["montecarlo", SCEN.name, "--runs", "1", "--workers", "1", "--quiet", "--set", short[0], "--set", short[1]]
    assert cli_main(base + ["--estimators", "single"]) == 0
    assert cli_main(base) == 0
    want_sel = f"{SCEN.name}_montecarlo" + _tag(short + ["--estimators=single"])
    want_all = f"{SCEN.name}_montecarlo" + _tag(short)
    assert sorted(os.listdir(tmp_path / "out")) == sorted([want_sel, want_all])
    assert check_campaign_manifest(str(tmp_path / "out" / want_sel)) == []
