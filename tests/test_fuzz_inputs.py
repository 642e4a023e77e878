"""Property-based fuzz of the loading and validation layer: Hypothesis mutates the
shipped scenario YAMLs and ``--set`` strings and runs ``drake-att check`` on them in this
process.

What it guards, for every mutation:

* ``main(["check", FILE])`` / ``main(["check", SHIPPED, "--set", S, ...])`` returns 0 or 2 -
  never another code, never raises (argparse included), never prints a traceback;
* an exit 2 ends with one ``drake-att ...`` line, and no stderr line is longer than ~1000
  characters (values in messages are truncated);
* ``check`` writes nothing: the example's folder holds exactly the file the test wrote,
  unchanged, and the file-system tripwire of ``test_hostile_inputs`` records no write anywhere
  else; no simulation starts; memory stays under the same cap.

Mutations of a shipped YAML (1-3 per example): delete a line, duplicate a line, replace a
line's scalar value or one number in it with a nasty token (1e300, -1, nan, .inf, '', a very
long string, ``!!python/object:os.system``, ``*undefined_alias``, ``&a``, ``[``, ``{``, unicode,
NUL, a lone surrogate...) or random text, insert random text. ``--set`` strings are a real or
bogus field path joined to a nasty token, random text or a random number, or random text
alone. Hypothesis runs derandomized (tests/conftest.py): the same examples every run.
"""

from __future__ import annotations

import os
import re
import tempfile

import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st
from test_hostile_inputs import BOMB, S, call_cli, message_problems, snapshot

pytestmark = pytest.mark.timeout(300)

SCENARIO_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "drake_att", "scenarios")
SHIPPED = {
    f[:-5]: open(os.path.join(SCENARIO_DIR, f), encoding="utf-8").read()
    for f in sorted(os.listdir(SCENARIO_DIR))
    if f.endswith(".yaml")
}

NASTY = [
    "1e300",
    "1.0e300",
    "-1e300",
    "-1",
    "0",
    "-0.0",
    "1e-300",
    "nan",
    ".nan",
    ".inf",
    "-.inf",
    "inf",
    "''",
    '""',
    "null",
    "~",
    "true",
    "no",
    "x" * 5000,
    "'" + "y" * 3000 + "'",
    "!!python/object:os.system",
    "!!python/object/apply:os.system ['touch PWNED']",
    "!!python/name:os.system",
    "!foo 1",
    "!!binary aGVsbG8=",
    "*undefined_alias",
    "&a",
    "&a [*a]",
    "[",
    "{",
    "]",
    "}",
    "[1, 2, 3]",
    "{a: 1}",
    "[[[[[[[[",
    "'unterminated",
    '"unterminated',
    "- a",
    ":",
    ": :",
    "|",
    ">",
    "@",
    "`",
    "%TAG",
    "---",
    "...",
    "0x7fffffffffffffff",
    "99999999999999999999999",
    "9" * 5000,
    "1_000",
    "0o777",
    "2001-12-14",
    "Ünïcødé",
    "姿勢",
    "\u202e",
    "\ufeff",
    "\x00",
    "a\x00b",
    "\x07",
    "\t",
    "\r",
    "\udcff",
    "\\",
    "../../x",
    "/",
]
_TOKEN = st.one_of(st.sampled_from(NASTY), st.sampled_from(NASTY), st.text(max_size=20))
_SCALAR_LINE = re.compile(r"^(\s*-?\s*[A-Za-z_][A-Za-z0-9_]*:[ \t]+)(\S.*)$")
_NUMBER = re.compile(r"-?\d+(\.\d+)?([eE][-+]?\d+)?")


@st.composite
def mutated_yaml(draw):
    """(shipped scenario name, mutated YAML text)."""
    name = draw(st.sampled_from(sorted(SHIPPED)))
    lines = SHIPPED[name].splitlines()
    for _ in range(draw(st.integers(1, 3))):
        if not lines:
            lines = [""]
        i = draw(st.integers(0, len(lines) - 1))
        op = draw(st.sampled_from(["delete", "duplicate", "scalar", "scalar", "number", "insert"]))
        if op == "delete":
            del lines[i]
        elif op == "duplicate":
            lines.insert(i, lines[i])
        elif op == "insert":
            lines.insert(i, draw(st.one_of(_TOKEN, st.text(max_size=40))))
        elif op == "scalar":
            candidates = [j for j, line in enumerate(lines) if _SCALAR_LINE.match(line)]
            if candidates:
                j = draw(st.sampled_from(candidates))
                lines[j] = _SCALAR_LINE.sub(lambda m: m.group(1) + draw(_TOKEN), lines[j])
        else:
            candidates = [
                j for j, line in enumerate(lines) if _NUMBER.search(line) and not line.lstrip().startswith("#")
            ]
            if candidates:
                j = draw(st.sampled_from(candidates))
                spans = [m.span() for m in _NUMBER.finditer(lines[j])]
                a, b = draw(st.sampled_from(spans))
                lines[j] = lines[j][:a] + draw(_TOKEN) + lines[j][b:]
    return name, "\n".join(lines) + "\n"


_PATHS = [
    "name",
    "description",
    "plugins",
    "duration_s",
    "seed",
    "simulation",
    "simulation.integration_scheme",
    "simulation.max_step_size_s",
    "simulation.accuracy",
    "simulation.use_error_control",
    "orbit",
    "orbit.altitude_km",
    "orbit.inclination_deg",
    "orbit.raan_deg",
    "plant",
    "plant.inertia_kg_m2",
    "plant.initial_attitude_rpy_deg",
    "plant.initial_rate_deg_per_s",
    "plant.disturbance_torque_N_m",
    "sensors",
    "sensors.gyro",
    "sensors.0",
    "sensors.1",
    "sensors.2",
    "sensors.gyro.period_s",
    "sensors.gyro.sample_rate_hz",
    "sensors.gyro.arw_deg_per_rt_h",
    "sensors.gyro.rrw_deg_per_h15",
    "sensors.gyro.initial_bias_deg_per_h",
    "sensors.gyro.misalignment_urad",
    "sensors.gyro.scale_factor_error_ppm",
    "sensors.gyro.name",
    "sensors.st1",
    "sensors.st1.period_s",
    "sensors.st1.mode",
    "sensors.st1.mounting",
    "sensors.st1.mounting.psi_phi_theta_deg",
    "sensors.st1.sigma_boresight_arcsec",
    "sensors.st1.sigma_cross_boresight_arcsec",
    "sensors.st1.name",
    "estimators",
    "estimators.single",
    "estimators.0",
    "estimators.single.period_s",
    "estimators.single.gyro",
    "estimators.single.star_trackers",
    "estimators.single.star_trackers.0",
    "estimators.single.initial_attitude_rpy_deg",
    "estimators.single.initial_attitude_sigma_deg",
    "estimators.single.initial_bias_sigma_deg_per_h",
    "estimators.single.innovation_gate_probability",
    "estimators.single.name",
    "scoring",
    "scoring.score_from_s",
    "scoring.convergence_threshold_deg",
    "bogus",
    "sensors.bogus.period_s",
    "estimators.99.period_s",
    "plant.bogus",
    "",
    ".",
    "..",
    "duration_s.x",
    "sensors.-1",
    "näme",
]
_VALUE = st.one_of(
    _TOKEN,
    st.floats().map(repr),
    st.integers().map(str),
    st.lists(st.floats(), max_size=4).map(lambda v: "[" + ", ".join(map(repr, v)) + "]"),
)
_SETTING = st.one_of(
    st.builds(lambda p, v: f"{p}={v}", st.sampled_from(_PATHS), _VALUE),
    st.builds(lambda p, v: f"{p}=={v}", st.sampled_from(_PATHS), _VALUE),
    st.sampled_from(_PATHS),
    st.text(max_size=40),
)

_FUZZ = settings(deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _problems(call, folder, before) -> list[str]:
    """The hostile suite's contract for a call (exit 0 or 2, no traceback, short lines, a last
    `drake-att` line, no write outside, no simulation), and no file of the folder changed."""
    event(f"exit {call.code}")  # --hypothesis-show-statistics: how many examples pass / are refused
    problems = message_problems(call, (0, 2))
    after = snapshot(folder)
    if after != before:
        problems.append(f"check changed files: {sorted(set(after) ^ set(before)) or 'contents'}")
    return problems


def _pinned(old: str, new: str) -> str:
    """The shipped single-tracker YAML with ``old`` replaced by ``new``."""
    assert SHIPPED[S].count(old) == 1, old  # the shipped file changed: update the pinned example
    return SHIPPED[S].replace(old, new)


def _in_fresh_folder(tmp_path, files: dict):
    """A new folder under ``tmp_path`` holding ``files`` (name -> bytes), made the current
    folder; returns (folder, previous cwd)."""
    folder = os.path.realpath(tempfile.mkdtemp(dir=tmp_path))
    for name, data in files.items():
        with open(os.path.join(folder, name), "wb") as f:
            f.write(data)
    previous = os.getcwd()
    os.chdir(folder)
    return folder, previous


@pytest.mark.slow
@settings(_FUZZ, max_examples=120)
@given(mutated=mutated_yaml())
# Pinned examples (always run, also under the derandomized profile): mutations found by the
# explore profile, and the bomb.
@example(mutated=(S, _pinned("duration_s: 5000.0", "duration_s: " + "9" * 5000)))
@example(mutated=(S, _pinned("seed: 1\n", f"seed: 1\nplugins: {BOMB}\n")))
def test_check_of_a_mutated_shipped_yaml_exits_0_or_2(mutated, tmp_path, capfd):
    name, text = mutated
    folder, previous = _in_fresh_folder(tmp_path, {"s.yaml": text.encode("utf-8", "surrogateescape")})
    try:
        before = snapshot(folder)
        call = call_cli(["check", "s.yaml"], capfd, folder)
        problems = _problems(call, folder, before)
    finally:
        os.chdir(previous)
    assert not problems, (
        f"mutation of {name}.yaml:\n  - "
        + "\n  - ".join(problems)
        + "\n--- s.yaml ---\n"
        + text[:3000]
        + "\n"
        + call.describe()
    )


@settings(_FUZZ, max_examples=80)
@given(settings_=st.lists(_SETTING, min_size=1, max_size=3))
@example(settings_=["seed=" + "9" * 5000])
@example(settings_=[f"description={BOMB}"])
def test_check_with_fuzzed_set_strings_exits_0_or_2(settings_, tmp_path, capfd):
    argv = ["check", S]
    for s in settings_:
        argv += ["--set", s]
    folder, previous = _in_fresh_folder(tmp_path, {})
    try:
        before = snapshot(folder)
        call = call_cli(argv, capfd, folder)
        problems = _problems(call, folder, before)
    finally:
        os.chdir(previous)
    assert not problems, "\n  - ".join(problems) + "\n" + call.describe()
