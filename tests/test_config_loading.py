"""The one loading layer (drake_att/scenarios/config.py, registry.py) and the CLI's guard
(drake_att/cli.py): bounded YAML (size, alias expansion, nesting), tags that never run
code, wrong types refused naming their field path, plug-ins imported only from places the
user chose and never from a result folder without --allow-plugins, and the guard that turns
any unexpected error into one line (exit 1) with the traceback only under --debug."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drake_att import cli
from drake_att.scenarios import config as cfg
from drake_att.scenarios.config import ConfigError, apply_overrides, load_scenario
from drake_att.scenarios.library import scenario_path

SHIPPED = Path(scenario_path("cubesat_single_star_tracker")).read_text()
REPO = Path(__file__).resolve().parents[1]


def refused(text, needle, seconds=3.0):
    """Refused naming ``needle``, one line, within ``seconds`` of this process's CPU time (a
    hang guard: an unbounded parse of these inputs runs for minutes; CPU time, not wall time,
    so that a loaded machine does not fail it)."""
    start = time.process_time()
    with pytest.raises(ConfigError) as e:
        load_scenario(text=text)
    elapsed = time.process_time() - start
    assert needle in str(e.value), str(e.value)
    assert elapsed < seconds, elapsed
    assert "\n" not in str(e.value) and len(str(e.value)) < 1000
    return str(e.value)


# --------------------------------------------------------------------------------------
# Bounds
# --------------------------------------------------------------------------------------
def _laughs(levels, width=9, where="plugins"):
    """A YAML "billion laughs": each level lists the previous one ``width`` times."""
    lines = ["name: x", f"{where}: &a0 [" + ", ".join(['"lol"'] * width) + "]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]" for i in range(1, levels)]
    return "\n".join(lines) + "\n"


def test_an_alias_bomb_is_refused_in_milliseconds():
    text = _laughs(10)  # 9^10 = 3.5e9 strings once expanded, from ~1 KB
    assert len(text) < 1200
    refused(text, "expands to more than", seconds=0.5)


def test_the_expansion_limit_is_the_expanded_node_count():
    # Expanded nodes of _laughs(levels, w) down the "a<last>" chain: the plugins list is
    # 1 + w nodes, each next level 1 + w * (previous) nodes. Computed here from that count.
    def expanded(levels, w):
        n = 1 + w
        for _ in range(1, levels):
            n = 1 + w * n
        return n

    w = 6
    levels = max(k for k in range(1, 12) if expanded(k, w) <= cfg.MAX_YAML_NODES)
    # Just inside: refused later for the unknown top-level fields, not for the size.
    msg = refused(_laughs(levels, w), "unknown field")
    assert "expands" not in msg
    refused(_laughs(levels + 1, w), "expands to more than")


def test_a_recursive_alias_and_deep_nesting_are_refused():
    refused("name: x\nplugins: &r [*r]\n", "refers to its own anchor")
    refused("name: " + "[" * 10000 + "]" * 10000 + "\n", "nested more than")
    refused("name: " + "{a: " * 5000 + "}" * 5000 + "\n", "nested more than")
    # The limit is the composed depth: 60 levels of lists still parse (and fail as a name).
    refused("name: " + "[" * 60 + "]" * 60 + "\n", "name")


def test_file_size_encoding_and_binary_are_refused_naming_the_file(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_text(SHIPPED + "#" * (cfg.MAX_SCENARIO_BYTES + 1))
    latin = tmp_path / "latin.yaml"
    latin.write_bytes(SHIPPED.replace("Paper S3", "Papier \xe9").encode("latin-1"))
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"name: x\n\x00\x01\x02")
    for path, needle in ((big, "larger than"), (latin, "not UTF-8"), (binary, "binary")):
        with pytest.raises(ConfigError) as e:
            load_scenario(filename=str(path))
        assert str(path) in str(e.value) and needle in str(e.value)
    with pytest.raises(ConfigError, match="larger than"):
        load_scenario(text="#" * (cfg.MAX_SCENARIO_BYTES + 1))


# --------------------------------------------------------------------------------------
# Tags never run code
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "value",
    [
        "!!python/object/apply:os.system ['touch {marker}']",
        "!!python/object/new:os.system ['touch {marker}']",
        "!!python/name:os.system",
        "!foo 20",
        "!MekfConfig 20",
    ],
)
def test_a_tag_on_a_value_is_refused_and_runs_nothing(tmp_path, value):
    marker = tmp_path / "ran"
    v = value.format(marker=marker)
    refused(SHIPPED.replace("duration_s: 5000.0", f"duration_s: {v}"), "tag")
    with pytest.raises(ConfigError, match="--set"):
        apply_overrides(load_scenario(text=SHIPPED), [f"duration_s={v}"])
    assert not marker.exists()


def test_a_tagged_top_level_and_an_unknown_section_tag_are_refused():
    refused("!MekfConfig\nname: x\n", "top level")
    refused(SHIPPED.replace("!MekfConfig", "!NoSuchConfig"), "unknown type !NoSuchConfig")
    refused(SHIPPED.replace("plant: !RigidBodyConfig", "plant: !GyroConfig"), "plant")


# --------------------------------------------------------------------------------------
# Types, paths, --set
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "old, new, needle",
    [
        ("duration_s: 5000.0", "duration_s: five", "duration_s: got 'five'; must be a number"),
        ("seed: 1", "seed: one", "seed: got 'one'; must be an integer"),
        ("seed: 1", "seed: 1.5", "seed: got 1.5; must be an integer"),
        ("inertia_kg_m2: [0.042, 0.042, 0.0067]", "inertia_kg_m2: heavy", "plant.inertia_kg_m2: got 'heavy'"),
        ("inertia_kg_m2: [0.042, 0.042, 0.0067]", "inertia_kg_m2: [a, b, c]", "plant.inertia_kg_m2[0]: got 'a'"),
        ("use_error_control: false", "use_error_control: 3", "simulation.use_error_control: got 3"),
        ("name: cubesat_single_star_tracker", "name: [a]", "name: got ['a']; must be a text"),
        ("  period_s: 0.1\n", "  period_s: 0.1\n  bogus: 3\n", "sensors[1] (st1, !StarTrackerConfig): unknown field"),
        (
            "mounting: !PaperS3Eq7Mounting {",
            "mounting: !PaperS3Eq7Mounting {zzz: 1, ",
            "sensors[1] (st1, !StarTrackerConfig).mounting: unknown field(s) ['zzz']",
        ),
        (
            "  star_trackers: [st1]",
            "  star_trackers: st1",
            "estimators[0] (single, !MekfConfig).star_trackers: got 'st1'",
        ),
        (
            "scoring:\n  score_from_s: 500.0\n  convergence_threshold_deg: 0.05\n",
            "scoring: 3\n",
            "scoring: got 3; must be a section",
        ),
    ],
)
def test_a_wrong_type_is_refused_naming_its_field_path(old, new, needle):
    assert old in SHIPPED
    refused(SHIPPED.replace(old, new), needle)


def test_an_empty_list_section_is_refused_naming_it():
    text = SHIPPED[: SHIPPED.index("estimators:")] + "estimators:\nscoring:\n  score_from_s: 500.0\n"
    refused(text, "estimators: got None; must be a list")


@pytest.mark.parametrize(
    "override, needle",
    [
        ("duration_s=[", "--set 'duration_s': invalid YAML"),
        ("name=null", "--set name: got null"),
        ("name=", "--set name: got null"),
        ("plant={bogus: 1}", "--set plant.bogus: unknown field"),
        ("plant=5", "plant is a section"),
        ("=3", "dotted field path"),
        ("a..b=1", "dotted field path"),
        ("duration_s", "expected PATH=VALUE"),
        ("sensors.9.period_s=1", "index 9 out of range"),
        ("sensors.nope.period_s=1", "no element named 'nope'"),
        ("plugins=" + "[" * 100 + "]" * 100, "nested more than"),
    ],
)
def test_set_is_refused_naming_the_override(override, needle):
    with pytest.raises(ConfigError) as e:
        apply_overrides(load_scenario(text=SHIPPED), [override])
    assert needle in str(e.value), str(e.value)


def test_set_a_section_from_a_mapping_sets_its_fields_and_null_unsets_an_optional_one():
    s = apply_overrides(load_scenario(text=SHIPPED), ["plant={inertia_kg_m2: [1, 2, 3]}", "orbit=null"])
    assert s.plant.inertia_kg_m2 == [1.0, 2.0, 3.0]
    assert s.plant.initial_rate_deg_per_s == [-0.5, 0.5, 0.5]  # the other fields keep their values
    assert s.orbit is None


# --------------------------------------------------------------------------------------
# Plug-ins: only from places the user chose, never from a result folder unasked
# --------------------------------------------------------------------------------------
def _marker_module(folder: Path, name: str) -> Path:
    marker = folder / f"{name}.ran"
    (folder / f"{name}.py").write_text(f"open({str(marker)!r}, 'w').write('imported')\n")
    return marker


def test_a_plugin_found_only_elsewhere_on_sys_path_is_not_imported(tmp_path, monkeypatch):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    marker = _marker_module(elsewhere, "stray_plugin_mod")
    monkeypatch.syspath_prepend(str(elsewhere))
    monkeypatch.chdir(REPO)
    with pytest.raises(ConfigError, match="neither the current folder"):
        load_scenario(text="name: x\nplugins: [stray_plugin_mod]\n")
    assert not marker.exists()
    # The same module from the current folder is the user's choice, and is imported.
    monkeypatch.chdir(elsewhere)
    load_scenario(text="name: x\nplugins: [stray_plugin_mod]\n")
    assert marker.exists()


def test_a_result_folder_never_imports_a_plugin_without_allow_plugins(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    marker = _marker_module(tmp_path, "folder_plugin_mod")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ConfigError, match="--allow-plugins"):
        load_scenario(text="name: x\nplugins: [folder_plugin_mod]\n", new_plugins=False)
    assert not marker.exists()
    with pytest.raises(ConfigError, match="expected a module name"):
        load_scenario(text="name: x\nplugins: ['os; rm -rf /']\n")


def test_score_in_a_downloaded_folder_does_not_run_its_module(tmp_path, capsys):
    """`python -m drake_att.cli score .` puts the folder on sys.path: the module beside the
    folder's config.yaml would be found - and is still not imported."""
    folder = tmp_path / "downloaded"
    folder.mkdir()
    (folder / "config.yaml").write_text(SHIPPED.replace("seed: 1", "seed: 1\nplugins: [evil_mod_xyz]"))
    (folder / "log.npz").write_bytes(b"PK")
    marker = _marker_module(folder, "evil_mod_xyz")
    r = subprocess.run(
        [sys.executable, "-m", "drake_att.cli", "score", "."],
        cwd=folder,
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg"),
    )
    assert r.returncode == 2, r.stderr
    assert "--allow-plugins" in r.stderr.strip().splitlines()[-1] and "Traceback" not in r.stderr
    assert not marker.exists()


# --------------------------------------------------------------------------------------
# The CLI's guard
# --------------------------------------------------------------------------------------
def test_an_unexpected_error_is_one_line_exit_1_and_debug_shows_the_traceback(monkeypatch, capsys):
    def broken(args):
        raise ZeroDivisionError("boom")

    monkeypatch.setattr(cli, "_cmd_list", broken)
    assert cli.main(["list"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "internal error: ZeroDivisionError: boom" in err[0] and "--debug" in err[0]
    with pytest.raises(ZeroDivisionError):
        cli.main(["list", "--debug"])


def test_argparse_errors_are_one_line_exit_2(capsys):
    for argv in (["run", "--bogus"], [], ["nope"], ["montecarlo", "--runs", "x"]):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("drake-att"), err


def test_check_validates_without_simulating(capsys):
    assert (
        cli.main(["check", "cubesat_single_star_tracker", "--set", "duration_s=20", "--set", "scoring.score_from_s=5"])
        == 0
    )
    assert "valid" in capsys.readouterr().out
    assert cli.main(["check", "cubesat_single_star_tracker", "--set", "duration_s=five"]) == 2
    assert "duration_s" in capsys.readouterr().err


@pytest.mark.slow
def test_sigterm_exits_143_and_leaves_no_folder(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "drake_att.cli", "run", "cubesat_dual_star_tracker", "--out", "r", "--no-figures"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg"),
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # wait until the simulation has started
        line = proc.stderr.readline()
        if "t =" in line or "%" in line:
            break
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err[-2000:]
    assert "Traceback" not in err and "terminated" in err
    assert sorted(os.listdir(tmp_path)) == []  # no result, no staging folder, no lock


def test_a_campaign_counts_the_memory_of_every_local_worker(tmp_path, monkeypatch, capsys):
    """A run that fits once but not twice: `check` passes, a campaign of 2 local workers is
    refused naming the dominant field, and one of a single worker is not refused for it."""
    from drake_att.scenarios import preflight
    from drake_att.scenarios.library import load

    scenario = apply_overrides(load("s0_particle_filters_small_error"), ["estimators.1.num_particles=200000"])
    one_run = preflight.memory_estimate(scenario).total_bytes
    monkeypatch.setattr(preflight, "available_memory_bytes", lambda: 1.5 * one_run)
    monkeypatch.chdir(tmp_path)
    args = ["s0_particle_filters_small_error", "--set", "estimators.1.num_particles=200000"]
    assert cli.main(["check", *args]) == 0
    capsys.readouterr()
    assert cli.main(["montecarlo", *args, "--runs", "4", "--workers", "2", "--out", "c"]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "num_particles" in last and "2 runs at once" in last
    assert os.listdir(tmp_path) == []


def test_a_prescribed_rpy_truth_with_an_orbit_is_refused():
    """Its breakpoints are relative to inertial while estimates start relative to the orbit
    frame: on S2's dynamic scenario with an orbit, a start at the truth's own rpy would be
    90 deg off. Refused naming orbit."""
    text = Path(scenario_path("s2_indoor_dynamic")).read_text()
    refused(text + "orbit: {altitude_km: 500.0}\n", "orbit: got 'set'")


# --------------------------------------------------------------------------------------
# What config's mutation sample found untested
# --------------------------------------------------------------------------------------
def test_set_by_name_lists_the_names_and_sets_a_whole_list_item_from_a_mapping():
    s = load_scenario(text=SHIPPED)
    with pytest.raises(ConfigError, match=r"names: \['gyro', 'st1'\]"):
        apply_overrides(s, ["sensors.nope.period_s=1"])
    t = apply_overrides(s, ["estimators.single={initial_attitude_sigma_deg: 1.5}"])
    assert t.estimators[0].initial_attitude_sigma_deg == 1.5 and t.estimators[0].period_s == 1.0


def test_long_values_and_paths_are_cut_in_messages():
    s = load_scenario(text=SHIPPED)
    with pytest.raises(ConfigError) as e:
        apply_overrides(s, ["plant=[" + ", ".join(["x" * 20] * 40) + "]"])  # 40 items: rendered, then cut
    assert "...; plant is a section" in str(e.value) and len(str(e.value)) < 1000
    long_path = "a" * 150
    with pytest.raises(ConfigError) as e:
        apply_overrides(s, [f"{long_path}=["])
    # The path is rendered (quoted: 152 characters) and cut at 100.
    assert str(e.value).startswith(f"--set '{'a' * 99}...: invalid YAML")


def test_a_sensor_listed_twice_is_refused_with_the_rule():
    with pytest.raises(ConfigError, match=r"star_trackers: got \['st1', 'st1'\]; each sensor may be listed once"):
        load_scenario(text=SHIPPED.replace("star_trackers: [st1]", "star_trackers: [st1, st1]"))


def test_weights_and_second_quantities_through_the_validation_context():
    from drake_att.contract import SecondQuantity

    assert cfg.check_weights("w", [1, 3], 2) == [1.0, 3.0]
    for bad in ([1, -1], [0, 0]):
        with pytest.raises(ConfigError, match=r"^w: got .*weights must be >= 0 with a positive sum"):
            cfg.check_weights("w", bad, 2)
    s = load_scenario(text=SHIPPED)
    checks = cfg.ValidationContext(s, {c.name: c for c in s.sensors}, {c.name: c for c in s.estimators})
    assert checks.second_quantity("single") == SecondQuantity.GYRO_BIAS
    # A fusion's second quantity is a function of its config (its sources' common one).
    dual = load_scenario(filename=scenario_path("cubesat_dual_star_tracker"))
    checks = cfg.ValidationContext(dual, {c.name: c for c in dual.sensors}, {c.name: c for c in dual.estimators})
    assert checks.second_quantity("decentralized") == SecondQuantity.GYRO_BIAS


@pytest.mark.parametrize("score_from", ["60", "60.0", "61"])
def test_a_scoring_window_starting_at_or_after_the_end_is_refused(score_from):
    """``scoring.score_from_s`` < ``duration_s`` is exclusive: a window from the last instant
    on holds no sample to score."""
    from drake_att.scenarios.library import load

    with pytest.raises(ConfigError, match=r"^scoring\.score_from_s: got .*; must be < duration_s \(60"):
        apply_overrides(load("cubesat_single_star_tracker"), ["duration_s=60", f"scoring.score_from_s={score_from}"])
    s = apply_overrides(load("cubesat_single_star_tracker"), ["duration_s=60", "scoring.score_from_s=59.999"])
    assert s.scoring.score_from_s == 59.999


def test_a_shortened_run_is_told_to_move_its_scoring_window(drake_att_cli):
    """``--set duration_s=60`` alone on a scenario scored from 500 s: the one-line refusal says
    which other setting to change, with a value that is accepted."""
    r = drake_att_cli("check", "cubesat_single_star_tracker", "--set", "duration_s=60")
    assert r.returncode == 2
    last = r.stderr.strip().splitlines()[-1]
    assert "scoring.score_from_s: got 500" in last and "--set scoring.score_from_s=30" in last, last
    fixed = drake_att_cli(
        "check", "cubesat_single_star_tracker", "--set", "duration_s=60", "--set", "scoring.score_from_s=30"
    )
    assert fixed.returncode == 0, fixed.stderr[-2000:]
