"""Every bad input the reliability review listed gets exit code 2 and a one-line
message naming the field or file, the value and what is allowed — never a traceback; Ctrl-C
exits 130 and leaves no result folder behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

ENV = dict(os.environ, MPLBACKEND="Agg")


def _cli(*args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "drake_att.cli", *args], capture_output=True, text=True, cwd=cwd, env=ENV
    )


CASES = {
    # id: (files to write {name: text}, CLI args, the message must contain)
    "yaml_syntax_error": ({"s.yaml": "name: x\nduration_s: [1, 2\n"}, ["run", "s.yaml"], "s.yaml"),
    "empty_file": ({"s.yaml": ""}, ["run", "s.yaml"], "empty"),
    "top_level_not_a_mapping": ({"s.yaml": "- 1\n- 2\n"}, ["run", "s.yaml"], "mapping"),
    "duplicate_key": ({"s.yaml": "name: a\nname: b\n"}, ["run", "s.yaml"], "name"),
    "unknown_top_level_field": ({"s.yaml": "name: a\nbogus: 1\n"}, ["run", "s.yaml"], "bogus"),
    "string_for_a_number": ({}, ["run", "cubesat_single_star_tracker", "--set", "duration_s=five"], "duration_s"),
    "set_a_section_to_a_number": ({}, ["run", "cubesat_single_star_tracker", "--set", "plant=5"], "plant"),
    "set_a_sensor_to_a_number": ({}, ["run", "cubesat_single_star_tracker", "--set", "sensors.st1=5"], "sensors.st1"),
    "unknown_override_field": ({}, ["run", "cubesat_single_star_tracker", "--set", "sensors.st1.bogus=1"], "bogus"),
    "seed_too_large": ({}, ["run", "cubesat_single_star_tracker", "--seed", "99999999999999999999"], "seed"),
    "seed_2_to_the_32": ({}, ["run", "cubesat_single_star_tracker", "--seed", str(2**32)], "seed"),
    "negative_seed": ({}, ["run", "cubesat_single_star_tracker", "--seed=-1"], "seed"),
    "out_is_a_file": ({"taken": "x"}, ["run", "cubesat_single_star_tracker", "--out", "taken"], "taken"),
    "unknown_scenario": ({}, ["run", "no_such_scenario"], "no_such_scenario"),
    "bad_gate_probability": (
        {},
        ["run", "cubesat_single_star_tracker", "--set", "estimators.single.innovation_gate_probability=1.5"],
        "innovation_gate_probability",
    ),
    "score_missing_folder": ({}, ["score", "no_such_folder"], "no_such_folder"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_exits_2_with_a_message_naming_it(tmp_path, case):
    files, args, needle = CASES[case]
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    r = _cli(*args, cwd=tmp_path)
    assert r.returncode == 2, (case, r.returncode, r.stderr[-2000:])
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout, r.stderr[-2000:]
    message = [line for line in r.stderr.splitlines() if line.startswith("drake-att")]
    assert message and needle in message[-1], (case, r.stderr[-2000:])


@pytest.mark.slow
def test_ctrl_c_exits_130_and_leaves_no_result_folder(tmp_path):
    """SIGINT while the simulation runs: exit 130, a message, no traceback, no output folder
    (and no staging folder)."""
    # A CI runner may start the suite with SIGINT ignored (a background job), and Python then
    # installs no KeyboardInterrupt handler: give the child the default disposition, as a
    # terminal user's process has.
    proc = subprocess.Popen(
        [sys.executable, "-m", "drake_att.cli", "run", "cubesat_dual_star_tracker", "--out", "r", "--no-figures"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 120
    err = ""
    while time.monotonic() < deadline:  # wait until the simulation has started
        line = proc.stderr.readline()
        err += line
        if "t =" in line or "%" in line:
            break
    proc.send_signal(signal.SIGINT)
    out, rest = proc.communicate(timeout=120)
    err += rest
    assert proc.returncode == 130, err[-2000:]
    assert "Traceback" not in err and "interrupted" in err.lower(), err[-2000:]
    assert sorted(os.listdir(tmp_path)) == []
