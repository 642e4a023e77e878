"""Hostile inputs at the edges of ``drake-att``: a table of bad YAML files, ``--set``
strings, CLI options, result folders and output folders, each run through
``drake_att.cli.main`` in this process.

What it guards (DESIGN.md "The edges", docs/guide/cli.md):

* **One error path.** ``main(argv)`` never raises (argparse included) and never lets a
  traceback reach the user. A user error returns 2 and the last non-empty stderr line starts
  with ``drake-att`` and names the field path / option / file (the case's *needles*); no stderr
  line is longer than ~1000 characters (values are truncated); no ``usage:`` block.
* **Files.** Every file and folder under the test's folder - including a user's
  ``thesis/thesis.txt`` and ``notes.txt`` present in every case - is snapshotted as
  (relative path, size, SHA-256) before and after: a refused call changes nothing, a
  successful one changes only its output folder. A tripwire on the file-system calls
  (``open`` for writing, ``os.open``, ``mkdir``, ``rename``, ``replace``, ``remove``, ``rmdir``,
  ``rmtree``...) refuses and records any write outside the test's folder (so ``--out /`` or a
  scenario named ``../../x`` can never touch the machine, even while the library is wrong).
* **Validation before work.** A call that must be refused never starts a simulation (a
  sentinel replaces ``ScenarioDiagram.simulate``); ``check`` never simulates at all.
* **Bounded resources.** Every call runs under an address-space cap (~4 GiB above the
  current size), so a YAML bomb or ``num_particles: 1e9`` fails the test instead of the
  machine; the cases that must be refused "in milliseconds" also assert a wall-time bound.
* **Untrusted folders run no code.** Result folders whose ``config.yaml`` names a plug-in
  that lives in the folder, or whose ``log.npz`` / run files hold pickled object arrays, are
  refused and the would-be payload (a marker file) is never created.

A handful of cases need a fresh interpreter and run as subprocesses (the end of this file):
``python -m drake_att.cli score .`` inside a folder holding a plug-in module (the current
folder is on ``sys.path`` there), and a full disk simulated with ``RLIMIT_FSIZE``.

Conventions assumed from ``drake_att/outputs.py`` (the lead's implementation): a writer's
lock is ``.<name>.lock`` beside the target holding ``"<pid> <host>"``; staging folders are
``.<name>.writing-XXXXXXXX`` / ``.<name>.replaced-XXXXXXXX``.

Run as root: ``chmod`` does not make a folder read-only for root, so "cannot be created" is
tested with a path under a regular file (``notes.txt/sub``).
"""

from __future__ import annotations

import builtins
import contextlib
import dataclasses
import errno
import hashlib
import io
import os
import re
import resource
import shutil
import signal
import socket
import subprocess
import sys
import time
import traceback
import zipfile
from collections.abc import Callable

import numpy as np
import pytest

pytestmark = pytest.mark.timeout(180)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENARIO_DIR = os.path.join(REPO, "drake_att", "scenarios")
SHIPPED = sorted(f[:-5] for f in os.listdir(SCENARIO_DIR) if f.endswith(".yaml"))
S = "cubesat_single_star_tracker"
TINY_SET = ("--set", "duration_s=2", "--set", "scoring.score_from_s=0")
TINY = (*TINY_SET, "--no-figures", "--quiet")
MC_TINY = ("--runs", "2", "--workers", "1", *TINY_SET, "--quiet")
MAX_LINE = 1100  # "no stderr line longer than ~1000 characters"
BIG_FILE = 16 * 2**20  # files above this are snapshotted by (size, mtime), not hashed
ROOT_TOKEN = "@ROOT@"  # replaced by the test's folder in argv and in file contents

# --------------------------------------------------------------------------------------------
# A tiny, valid scenario (the single-star-tracker case, 2 s) that the YAML cases mutate
# --------------------------------------------------------------------------------------------
BASE = """\
name: hostile
description: tiny scenario for the hostile-input tests
duration_s: 2.0
seed: 1
simulation:
  integration_scheme: runge_kutta3
  use_error_control: false
  max_step_size_s: 0.1
orbit:
  altitude_km: 500.0
  inclination_deg: 97.5
plant: !RigidBodyConfig
  inertia_kg_m2: [0.042, 0.042, 0.0067]
  initial_attitude_rpy_deg: [2.0, -2.0, 2.0]
  initial_rate_deg_per_s: [-0.5, 0.5, 0.5]
  disturbance_torque_N_m: [1.0e-7, 1.0e-7, 1.0e-7]
sensors:
- !GyroConfig
  name: gyro
  period_s: 1.0
  sample_rate_hz: 300.0
  arw_deg_per_rt_h: 0.56
  rrw_deg_per_h15: 123.75
  initial_bias_deg_per_h: [12.0, 12.0, 12.0]
- !StarTrackerConfig
  name: st1
  period_s: 0.1
  mode: quaternion
  mounting: !PaperS3Eq7Mounting {psi_phi_theta_deg: [-90.0, 45.0, -90.0]}
  sigma_cross_boresight_arcsec: 5.0
  sigma_boresight_arcsec: 50.0
estimators:
- !MekfConfig
  name: single
  period_s: 1.0
  gyro: gyro
  star_trackers: [st1]
  initial_attitude_rpy_deg: [0.0, 0.0, 0.0]
  initial_bias_deg_per_h: [0.0, 0.0, 0.0]
  initial_attitude_sigma_deg: 5.0
  initial_bias_sigma_deg_per_h: 20.0
scoring:
  score_from_s: 0.0
  convergence_threshold_deg: 0.05
"""


def _set_value(text: str, key: str, occurrence: int, value: str) -> str:
    """``text`` with the value of the ``occurrence``-th ``key:`` line replaced by ``value``."""
    pattern = re.compile(rf"^(\s*-?\s*{re.escape(key)}:)[ \t].*$", re.M)
    matches = list(pattern.finditer(text))
    assert len(matches) > occurrence, (key, occurrence)  # the base text changed: fix the table
    m = matches[occurrence]
    return text[: m.start()] + f"{m.group(1)} {value}" + text[m.end() :]


def _sub(text: str, old: str, new: str) -> str:
    assert text.count(old) == 1, old  # the base text changed: fix the table
    return text.replace(old, new)


def _bomb(levels: int = 9, width: int = 9) -> str:
    """A "billion laughs" flow sequence (``width**levels`` leaves, ~1 KB of text) whose
    anchors are defined inside it: ``[&a0 [lol, ...], &a1 [*a0, ...], ...]``."""
    parts = ["&a0 [" + ", ".join(["lol"] * width) + "]"]
    for i in range(1, levels):
        parts.append(f"&a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]")
    return "[" + ", ".join(parts) + "]"


BOMB = _bomb()
assert len(BOMB) < 1500


def _nested_lists(depth: int) -> str:
    return "[" * depth + "]" * depth


def _nested_maps(depth: int) -> str:
    return "{a: " * depth + "1" + "}" * depth


# --------------------------------------------------------------------------------------------
# The harness: snapshot, tripwire, memory cap, no-simulation sentinel, in-process call
# --------------------------------------------------------------------------------------------
def snapshot(root) -> dict:
    """Every entry under ``root``: relative path -> ("dir",) | ("link", target) |
    ("file", size, sha256) | ("big", size, mtime_ns) | ("special", mode)."""
    root = os.fspath(root)
    state = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            path = os.path.join(dirpath, name)
            rel = os.path.relpath(path, root)
            st = os.lstat(path)
            if os.path.islink(path):
                state[rel] = ("link", os.readlink(path))
            elif os.path.isdir(path):
                state[rel] = ("dir",)
            elif not os.path.isfile(path):
                state[rel] = ("special", st.st_mode)
            elif st.st_size > BIG_FILE:
                state[rel] = ("big", st.st_size, st.st_mtime_ns)
            else:
                with open(path, "rb") as f:
                    state[rel] = ("file", st.st_size, hashlib.sha256(f.read()).hexdigest())
    return state


def changed_paths(before: dict, after: dict) -> list[str]:
    return sorted(p for p in set(before) | set(after) if before.get(p) != after.get(p))


def _under(path: str, prefix: str) -> bool:
    path, prefix = os.path.normpath(path), os.path.normpath(prefix)
    return path == prefix or path.startswith(prefix + os.sep)


_REAL_HOME = os.path.expanduser("~")
# Caches a library may legitimately write to outside the test's folder.
_CACHE_DIRS = tuple(
    os.path.realpath(p) + os.sep
    for p in filter(
        None,
        [
            os.path.join(_REAL_HOME, ".cache"),
            os.path.join(_REAL_HOME, ".config", "matplotlib"),
            os.environ.get("MPLCONFIGDIR"),
            os.environ.get("NUMBA_CACHE_DIR"),
        ],
    )
)
_WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND


class _Tripwire:
    """Refuses (PermissionError) and records every file-system write outside ``root``."""

    def __init__(self, root):
        self.root = os.path.realpath(os.fspath(root))
        self.escapes: list[str] = []

    def outside(self, path) -> bool:
        if isinstance(path, int) or path is None:
            return False
        try:
            p = os.path.realpath(os.path.abspath(os.fsdecode(path)))
        except (TypeError, ValueError):
            return False
        if _under(p, self.root) or "__pycache__" in p.split(os.sep):
            return False
        return not p.startswith(("/dev/", "/proc/") + _CACHE_DIRS)

    def guard(self, op: str, *paths):
        for path in paths:
            if self.outside(path):
                self.escapes.append(f"{op}({os.fsdecode(path)!r})")
                raise PermissionError(
                    errno.EACCES, f"hostile-input tripwire: {op} outside the test folder", os.fsdecode(path)
                )

    @contextlib.contextmanager
    def active(self):
        real = {
            name: getattr(os, name)
            for name in (
                "rename",
                "replace",
                "remove",
                "unlink",
                "rmdir",
                "mkdir",
                "open",
                "symlink",
                "link",
                "truncate",
            )
        }
        real_open, real_rmtree = builtins.open, shutil.rmtree
        t = self

        def two(name):
            def f(src, dst, *a, **k):
                if not (k.get("src_dir_fd") or k.get("dst_dir_fd")):
                    t.guard(name, src, dst)
                return real[name](src, dst, *a, **k)

            return f

        def one(name):
            def f(path, *a, **k):
                if k.get("dir_fd") is None:
                    t.guard(name, path)
                return real[name](path, *a, **k)

            return f

        def mkdir(path, *a, **k):
            if k.get("dir_fd") is None and not os.path.lexists(path):
                t.guard("mkdir", path)
            return real["mkdir"](path, *a, **k)

        def os_open(path, flags, *a, **k):
            if flags & _WRITE_FLAGS and k.get("dir_fd") is None:
                t.guard("os.open", path)
            return real["open"](path, flags, *a, **k)

        def open_(file, mode="r", *a, **k):
            if isinstance(mode, str) and any(c in mode for c in "wax+"):
                t.guard("open", file)
            return real_open(file, mode, *a, **k)

        def rmtree(path, *a, **k):
            t.guard("shutil.rmtree", path)
            return real_rmtree(path, *a, **k)

        with pytest.MonkeyPatch.context() as mp:
            for name in ("rename", "replace", "symlink", "link"):
                mp.setattr(os, name, two(name))
            for name in ("remove", "unlink", "rmdir", "truncate"):
                mp.setattr(os, name, one(name))
            mp.setattr(os, "mkdir", mkdir)
            mp.setattr(os, "open", os_open)
            mp.setattr(builtins, "open", open_)
            mp.setattr(io, "open", open_)
            mp.setattr(shutil, "rmtree", rmtree)
            yield self


def _vm_size() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


@contextlib.contextmanager
def memory_cap(extra: int = 4 * 2**30):
    """An address-space limit ``extra`` bytes above the current size (the hard limit is left
    alone, so it is lifted again afterwards): a runaway allocation raises MemoryError here."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = _vm_size() + extra
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    if soft != resource.RLIM_INFINITY:
        cap = min(cap, soft)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


class _SimulationStarted(Exception):
    pass


@contextlib.contextmanager
def no_simulation(record: list):
    """``ScenarioDiagram.simulate`` raises (and is recorded): an input that must be refused is
    refused before any simulation starts."""
    from drake_att.scenarios import builder

    def refuse(self, *a, **k):
        record.append(getattr(getattr(self, "scenario", None), "name", "?"))
        raise _SimulationStarted("hostile-input sentinel: a simulation started for an input that must be refused")

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(builder.ScenarioDiagram, "simulate", refuse)
        yield


@dataclasses.dataclass
class Call:
    argv: list
    code: object
    out: str
    err: str
    seconds: float
    raised: str | None
    escapes: list
    simulated: list

    def describe(self) -> str:
        return (
            f"argv={_short(self.argv)}\nexit code: {self.code!r}  ({self.seconds:.2f} s)\n"
            + (f"main() RAISED: {self.raised[-3000:]}\n" if self.raised else "")
            + (f"writes outside the test folder: {self.escapes}\n" if self.escapes else "")
            + (f"simulation started: {self.simulated}\n" if self.simulated else "")
            + f"--- stderr (tail) ---\n{self.err[-2500:]}\n--- stdout (tail) ---\n{self.out[-800:]}"
        )


def _short(argv) -> list:
    return [a if len(a) <= 120 else a[:100] + f"...<{len(a)} chars>" for a in argv]


def call_cli(argv, capfd, root, *, refuse_simulation: bool | None = None) -> Call:
    """``main(argv)`` in this process, its output captured, under the tripwire (no write
    outside ``root``), the memory cap and (for ``check`` and for inputs that must be refused)
    the no-simulation sentinel."""
    from _pytest.outcomes import OutcomeException

    from drake_att.cli import main

    argv = [str(a) for a in argv]
    if refuse_simulation is None:
        refuse_simulation = bool(argv) and argv[0] == "check"
    capfd.readouterr()
    tripwire, simulated = _Tripwire(root), []
    code, raised = None, None
    with contextlib.ExitStack() as stack:
        stack.enter_context(tripwire.active())
        if refuse_simulation:
            stack.enter_context(no_simulation(simulated))
        stack.enter_context(memory_cap())
        start = time.perf_counter()
        try:
            code = main(list(argv))
        except OutcomeException:  # pytest-timeout and friends
            raise
        except BaseException as e:  # noqa: BLE001 - the contract is that nothing escapes main()
            raised = f"{type(e).__name__}: {str(e)[:500]}\n{traceback.format_exc()}"
        seconds = time.perf_counter() - start
    out, err = capfd.readouterr()
    return Call(argv, code, out, err, seconds, raised, tripwire.escapes, simulated)


def message_problems(c: Call, code, needles=()) -> list[str]:
    """What is wrong with a call's exit code and messages (empty: all good). ``code`` is an
    int or a tuple of allowed ints."""
    problems = []
    allowed = code if isinstance(code, tuple) else (code,)
    if c.raised is not None:
        problems.append("main() raised instead of returning an exit code (never raise; argparse errors too)")
    elif c.code not in allowed:
        problems.append(f"exit code {c.code!r}, expected {' or '.join(map(str, allowed))}")
    if "Traceback" in c.err or "Traceback" in c.out:
        problems.append("a traceback reached the user")
    long = [len(line) for line in c.err.splitlines() if len(line) > MAX_LINE]
    if long:
        problems.append(f"stderr lines of {long[:5]} characters (max ~1000: truncate values)")
    if c.escapes:
        problems.append(f"writes outside the test folder: {c.escapes[:5]}")
    if c.simulated:
        problems.append("a simulation started for an input that must be refused before any work")
    lines = [line for line in c.err.splitlines() if line.strip()]
    if c.code == 2 and c.raised is None:
        if not lines or not lines[-1].startswith("drake-att"):
            problems.append("the last stderr line does not start with 'drake-att'")
        else:
            missing = [n for n in needles if n not in lines[-1]]
            if missing:
                problems.append(f"the last stderr line does not name {missing}")
        if any(line.startswith("usage:") for line in lines):
            problems.append("a usage block was printed (argparse errors are one line)")
    elif c.code == 0 and 0 in allowed and needles:
        missing = [n for n in needles if n not in c.err]
        if missing:
            problems.append(f"exit 0 without a message naming {missing}")
    return problems


# --------------------------------------------------------------------------------------------
# The table
# --------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Case:
    """One hostile input.

    argv: the CLI arguments (``@ROOT@`` is replaced by the test's folder).
    needles: strings the last stderr line must contain (exit 2), or some stderr line (exit 0).
    code: the exit code (or a tuple of allowed codes).
    files: relative path -> text/bytes written under the test's folder first.
    setup: ``setup(ctx)`` for anything else (copies of result folders, HOME, locks, patches).
    cwd: the current folder, relative to the test's folder.
    changes: relative paths under which a successful call may change files.
    max_s: wall-time bound of the call (for "refused in milliseconds" cases).
    may_simulate: an exit-2 case that may legitimately fail after simulating.
    ok_line: exit 0 prints a line with "OK" (``check``).
    expect: ``expect(ctx, call) -> list of problems`` for anything else.
    """

    argv: tuple
    needles: tuple = ()
    code: object = 2
    files: dict | None = None
    setup: Callable | None = None
    cwd: str = "."
    changes: tuple = ()
    max_s: float | None = None
    may_simulate: bool = False
    ok_line: bool = False
    expect: Callable | None = None


@dataclasses.dataclass
class Ctx:
    root: str
    monkeypatch: pytest.MonkeyPatch
    request: pytest.FixtureRequest
    cleanup: list

    def path(self, *parts) -> str:
        return os.path.join(self.root, *parts)

    @property
    def results(self) -> dict:
        """The module's shared result folders (made on first use)."""
        return self.request.getfixturevalue("result_folders")


CASES: dict[str, Case] = {}


def case(case_id: str, *argv, **kw) -> None:
    assert case_id not in CASES, case_id
    CASES[case_id] = Case(tuple(argv), **kw)


def _check_yaml(case_id: str, text, needles, code=2, **kw) -> None:
    """``drake-att check s.yaml`` with ``text`` (str or bytes) as s.yaml."""
    case(
        case_id, "check", "s.yaml", needles=tuple(needles), code=code, files={"s.yaml": text}, ok_line=(code == 0), **kw
    )


def _check_set(case_id: str, setting: str, needles, code=2, scenario=S, **kw) -> None:
    """``drake-att check SCENARIO --set setting``."""
    case(case_id, "check", scenario, "--set", setting, needles=tuple(needles), code=code, ok_line=(code == 0), **kw)


# ---- positive controls: the layer must not refuse what is valid ----------------------------
for _name in SHIPPED:
    case(f"check-ok-shipped-{_name}", "check", _name, code=0, ok_line=True)
_check_yaml("check-ok-base-yaml", BASE, (), code=0)
_check_yaml(
    "check-ok-legit-anchor-alias",
    _sub(
        _sub(BASE, "  initial_attitude_rpy_deg: [0.0, 0.0, 0.0]", "  initial_attitude_rpy_deg: &zero [0.0, 0.0, 0.0]"),
        "  initial_bias_deg_per_h: [0.0, 0.0, 0.0]",
        "  initial_bias_deg_per_h: *zero",
    ),
    (),
    code=0,
)
_check_yaml("check-ok-crlf-line-endings", BASE.replace("\n", "\r\n").encode(), (), code=0)
_check_yaml("check-ok-unicode-description", _set_value(BASE, "description", 0, "'Ünïcødé ✓ 姿勢推定 – ok'"), (), code=0)
_check_yaml("check-ok-or-refused-utf8-bom", b"\xef\xbb\xbf" + BASE.encode(), (), code=(0, 2))
for _i, _setting in enumerate(
    [
        "duration_s=600",
        "sensors.st1.sigma_boresight_arcsec=20",
        "estimators.single.initial_attitude_sigma_deg=1",
        "orbit.altitude_km=35786",
        "name=my_run-2",
        "plant.inertia_kg_m2=[1, 2, 2.5]",
        "seed=4294967295",
        "description=Ünïcødé ✓",
    ]
):
    _check_set(f"check-ok-set-{_setting.split('=')[0]}", _setting, (), code=0)
case(
    "run-ok-base-yaml",
    "run",
    "s.yaml",
    "--out",
    "fresh",
    "--no-figures",
    "--quiet",
    code=0,
    files={"s.yaml": BASE},
    changes=("fresh",),
)

# ---- YAML files: syntax ----------------------------------------------------------------------
_check_yaml("yaml-syntax-unclosed-flow-list", "name: x\nduration_s: [1, 2\n", ("s.yaml",))
_check_yaml("yaml-syntax-unclosed-flow-map", "name: x\nplant: {a: 1\n", ("s.yaml",))
_check_yaml("yaml-syntax-unclosed-quote", 'name: "abc\nduration_s: 2\n', ("s.yaml",))
_check_yaml("yaml-syntax-tab-indent", BASE.replace("  name: gyro", "\tname: gyro"), ("s.yaml",))
_check_yaml("yaml-syntax-bad-indent", _sub(BASE, "  period_s: 0.1\n", "     period_s: 0.1\n"), ("s.yaml",))
_check_yaml("yaml-syntax-colons", ": : :\n", ("s.yaml",))
_check_yaml("yaml-syntax-stray-close-bracket", BASE + "]\n", ("s.yaml",))
_check_yaml("yaml-syntax-two-documents", BASE + "---\nname: other\n", ("s.yaml",))
_check_yaml("yaml-syntax-directive-garbage", "%YAML 9.9\n%TAG ! !\n---\nname: x\n", ("s.yaml",))

# ---- YAML files: tags (never executed; a refused tag is exit 2 naming the file) -----------------
_PWN = "touch @ROOT@/PWNED"
_check_yaml(
    "yaml-tag-python-object-apply",
    _set_value(BASE, "name", 0, f'!!python/object/apply:os.system ["{_PWN}"]'),
    ("s.yaml",),
)
_check_yaml(
    "yaml-tag-python-object-new", _set_value(BASE, "name", 0, f'!!python/object/new:os.system ["{_PWN}"]'), ("s.yaml",)
)
_check_yaml("yaml-tag-python-name", _set_value(BASE, "duration_s", 0, "!!python/name:os.system"), ("s.yaml",))
_check_yaml("yaml-tag-python-module", _set_value(BASE, "duration_s", 0, "!!python/module:os"), ("s.yaml",))
_check_yaml("yaml-tag-python-object-top-level", "!!python/object:os.system {}\n", ("s.yaml",))
_check_yaml("yaml-tag-foo-on-scalar", _set_value(BASE, "duration_s", 0, "!foo 20"), ("s.yaml", "foo"))
_check_yaml("yaml-tag-foo-on-list", _set_value(BASE, "inertia_kg_m2", 0, "!foo [1, 1, 1]"), ("s.yaml", "foo"))
_check_yaml(
    "yaml-tag-unknown-plant", _sub(BASE, "plant: !RigidBodyConfig", "plant: !NoSuchPlantConfig"), ("NoSuchPlantConfig",)
)
_check_yaml("yaml-tag-unknown-sensor", _sub(BASE, "- !GyroConfig", "- !NoSuchSensorConfig"), ("NoSuchSensorConfig",))
_check_yaml(
    "yaml-tag-unknown-estimator", _sub(BASE, "- !MekfConfig", "- !NoSuchEstimatorConfig"), ("NoSuchEstimatorConfig",)
)
_check_yaml("yaml-tag-sensor-type-as-estimator", _sub(BASE, "- !MekfConfig", "- !GyroConfig"), ("estimators",))
_check_yaml("yaml-tag-estimator-type-as-plant", _sub(BASE, "plant: !RigidBodyConfig", "plant: !MekfConfig"), ("plant",))
_check_yaml("yaml-tag-binary-name", _set_value(BASE, "name", 0, "!!binary aGVsbG8="), ("name",))
_check_yaml("yaml-tag-set-plugins", _sub(BASE, "seed: 1\n", "seed: 1\nplugins: !!set {a, b}\n"), ("plugins",))
_check_yaml(
    "yaml-tag-timestamp-duration", _set_value(BASE, "duration_s", 0, "2001-12-14t21:59:43.10-05:00"), ("duration_s",)
)

# ---- YAML files: anchors, aliases, bombs -----------------------------------------------------
_check_yaml("yaml-alias-undefined", _set_value(BASE, "duration_s", 0, "*nope"), ("s.yaml",))
_check_yaml("yaml-alias-recursive-description", _set_value(BASE, "description", 0, "&r [*r]"), ("s.yaml",), max_s=3.0)
_check_yaml(
    "yaml-alias-recursive-plugins", _sub(BASE, "seed: 1\n", "seed: 1\nplugins: &r [*r]\n"), ("s.yaml",), max_s=3.0
)
_check_yaml(
    "yaml-merge-key-into-plant",
    _sub(
        BASE,
        "  inertia_kg_m2: [0.042, 0.042, 0.0067]\n",
        "  <<: {bogus_merged: 1}\n  inertia_kg_m2: [0.042, 0.042, 0.0067]\n",
    ),
    ("s.yaml",),
)
_check_yaml("yaml-bomb-in-plugins", _sub(BASE, "seed: 1\n", f"seed: 1\nplugins: {BOMB}\n"), ("s.yaml",), max_s=3.0)
_check_yaml("yaml-bomb-name-next-to-unknown-field", f"bogus: {BOMB}\nname: *a8\n", ("s.yaml",), max_s=3.0)
_check_yaml("yaml-bomb-in-description", _set_value(BASE, "description", 0, BOMB), ("s.yaml",), max_s=3.0)
_check_yaml("yaml-bomb-in-sensors", _sub(BASE, "sensors:\n", f"sensors: {BOMB}\nx_sensors:\n"), ("s.yaml",), max_s=3.0)
_check_yaml("yaml-bomb-as-inertia", _set_value(BASE, "inertia_kg_m2", 0, BOMB), ("s.yaml",), max_s=3.0)
_check_yaml("yaml-bomb-top-level-list", BOMB + "\n", ("s.yaml",), max_s=3.0)

# ---- YAML files: sizes, depth, encodings, binary, empty ----------------------------------------
_check_yaml(
    "yaml-size-2MiB-of-comments", BASE + ("# " + "x" * 98 + "\n") * (2 * 2**20 // 100 + 1), ("s.yaml",), max_s=2.0
)
_check_yaml(
    "yaml-size-2MiB-description",
    _set_value(BASE, "description", 0, "'" + "d" * (2 * 2**20) + "'"),
    ("s.yaml",),
    max_s=2.0,
)
case(
    "yaml-size-100MiB-sparse",
    "check",
    "big.yaml",
    needles=("big.yaml",),
    max_s=2.0,
    setup=lambda ctx: _sparse(ctx.path("big.yaml"), 100 * 2**20),
)
case("yaml-size-dev-zero", "check", "/dev/zero", needles=("/dev/zero",), max_s=3.0)
case("yaml-size-dev-null", "check", "/dev/null", needles=("/dev/null",))
_check_yaml("yaml-huge-string-field-600k", _set_value(BASE, "mode", 0, "'" + "z" * 600_000 + "'"), ("mode",))
_check_yaml("yaml-huge-unknown-key-200k", BASE + "k" * 200_000 + ": 1\n", ("s.yaml",))
_check_yaml("yaml-huge-number-5000-digits", _set_value(BASE, "duration_s", 0, "9" * 5000), ("duration_s",))
_check_yaml(
    "yaml-huge-list-20k",
    _set_value(BASE, "inertia_kg_m2", 0, "[" + ", ".join(["1.0"] * 20_000) + "]"),
    ("inertia_kg_m2",),
)
_check_yaml(
    "yaml-deep-nested-lists-10000", _set_value(BASE, "description", 0, _nested_lists(10_000)), ("s.yaml",), max_s=5.0
)
_check_yaml(
    "yaml-deep-nested-maps-10000", _set_value(BASE, "description", 0, _nested_maps(10_000)), ("s.yaml",), max_s=5.0
)
_check_yaml("yaml-deep-nested-lists-top-level", _nested_lists(10_000) + "\n", ("s.yaml",), max_s=5.0)
_check_yaml("yaml-deep-block-indent-1000", "".join(" " * i + "a:\n" for i in range(1000)), ("s.yaml",), max_s=5.0)
_check_yaml("yaml-encoding-latin1", _set_value(BASE, "description", 0, "café").encode("latin-1"), ("s.yaml",))
_check_yaml("yaml-encoding-utf16", BASE.encode("utf-16"), ("s.yaml",))
_check_yaml("yaml-encoding-invalid-utf8-in-key", BASE.encode() + b"\xff\xfe: 1\n", ("s.yaml",))
_check_yaml("yaml-binary-png", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)) * 4, ("s.yaml",))
_check_yaml("yaml-binary-elf", b"\x7fELF\x02\x01\x01\x00" + bytes(1000), ("s.yaml",))
_check_yaml("yaml-binary-random", np.random.default_rng(22).bytes(4096), ("s.yaml",))
_check_yaml("yaml-nul-in-value", _set_value(BASE, "description", 0, "a\x00b"), ("s.yaml",))
_check_yaml("yaml-control-chars", _set_value(BASE, "description", 0, "a\x07\x1b[31mred"), ("s.yaml",))
_check_yaml("yaml-empty-file", "", ("s.yaml",))
_check_yaml("yaml-whitespace-only", "   \n\n\t\n", ("s.yaml",))
_check_yaml("yaml-comments-only", "# nothing\n# here\n", ("s.yaml",))
_check_yaml("yaml-document-marker-only", "---\n", ("s.yaml",))
_check_yaml("yaml-null-document", "null\n", ("s.yaml",))
_check_yaml("yaml-top-level-scalar", "42\n", ("s.yaml",))
_check_yaml("yaml-top-level-string", "just a sentence\n", ("s.yaml",))
_check_yaml("yaml-top-level-list", "- 1\n- 2\n", ("s.yaml",))
case("yaml-file-is-a-folder", "check", "thesis", needles=("thesis",))
case("yaml-file-missing", "check", "no_such_file.yaml", needles=("no_such_file.yaml",))
case(
    "yaml-file-dangling-symlink",
    "check",
    "dangling.yaml",
    needles=("dangling.yaml",),
    setup=lambda ctx: os.symlink(ctx.path("nowhere.yaml"), ctx.path("dangling.yaml")),
)

# ---- YAML files: wrong types at every level (systematic) ---------------------------------------
# (label, key, occurrence in BASE, kind) -> wrong values per kind; the message names the key.
_FIELDS = [
    ("duration_s", "duration_s", 0, "F"),
    ("seed", "seed", 0, "I"),
    ("name", "name", 0, "N"),
    ("description", "description", 0, "S"),
    ("simulation.integration_scheme", "integration_scheme", 0, "E"),
    ("simulation.use_error_control", "use_error_control", 0, "B"),
    ("simulation.max_step_size_s", "max_step_size_s", 0, "F"),
    ("orbit.altitude_km", "altitude_km", 0, "F"),
    ("orbit.inclination_deg", "inclination_deg", 0, "F"),
    ("plant.inertia_kg_m2", "inertia_kg_m2", 0, "V"),
    ("plant.initial_attitude_rpy_deg", "initial_attitude_rpy_deg", 0, "V"),
    ("plant.initial_rate_deg_per_s", "initial_rate_deg_per_s", 0, "V"),
    ("plant.disturbance_torque_N_m", "disturbance_torque_N_m", 0, "V"),
    ("sensors.gyro.name", "name", 1, "N"),
    ("sensors.gyro.period_s", "period_s", 0, "F"),
    ("sensors.gyro.sample_rate_hz", "sample_rate_hz", 0, "F"),
    ("sensors.gyro.arw_deg_per_rt_h", "arw_deg_per_rt_h", 0, "F"),
    ("sensors.gyro.rrw_deg_per_h15", "rrw_deg_per_h15", 0, "F"),
    ("sensors.gyro.initial_bias_deg_per_h", "initial_bias_deg_per_h", 0, "V"),
    ("sensors.st1.name", "name", 2, "N"),
    ("sensors.st1.period_s", "period_s", 1, "F"),
    ("sensors.st1.mode", "mode", 0, "E"),
    ("sensors.st1.sigma_cross_boresight_arcsec", "sigma_cross_boresight_arcsec", 0, "F"),
    ("sensors.st1.sigma_boresight_arcsec", "sigma_boresight_arcsec", 0, "F"),
    ("estimators.single.name", "name", 3, "N"),
    ("estimators.single.period_s", "period_s", 2, "F"),
    ("estimators.single.gyro", "gyro", 0, "E"),
    ("estimators.single.star_trackers", "star_trackers", 0, "L"),
    ("estimators.single.initial_attitude_rpy_deg", "initial_attitude_rpy_deg", 1, "V"),
    ("estimators.single.initial_bias_deg_per_h", "initial_bias_deg_per_h", 1, "V"),
    ("estimators.single.initial_attitude_sigma_deg", "initial_attitude_sigma_deg", 0, "F"),
    ("estimators.single.initial_bias_sigma_deg_per_h", "initial_bias_sigma_deg_per_h", 0, "F"),
    ("scoring.score_from_s", "score_from_s", 0, "F"),
    ("scoring.convergence_threshold_deg", "convergence_threshold_deg", 0, "F"),
]
_WRONG = {
    "F": {"string": "five", "mapping": "{a: 1}", "list": "[1.0, 2.0]", "nan": ".nan"},
    "I": {"string": "one", "mapping": "{a: 1}", "float": "1.5", "list": "[1]"},
    "N": {"mapping": "{a: 1}", "list": "[a, b]", "empty": "''", "null": "null"},
    "S": {"mapping": "{a: 1}", "list": "[a, b]"},
    "E": {"mapping": "{a: 1}", "list": "[a]", "unknown": "no_such_choice"},
    "B": {"mapping": "{a: 1}", "string": "five", "list": "[true]"},
    "V": {"string": "five", "mapping": "{a: 1}", "nan": "[.nan, 0.0, 0.0]", "short": "[1.0, 2.0]"},
    "L": {"mapping": "{a: 1}", "unknown": "[no_such_tracker]", "duplicate": "[st1, st1]"},
}
for _label, _key, _occ, _kind in _FIELDS:
    for _what, _value in _WRONG[_kind].items():
        _check_yaml(f"yaml-type-{_label}-{_what}", _set_value(BASE, _key, _occ, _value), (_key,))

# ---- YAML files: physical ranges -----------------------------------------------------------
for _label, _key, _occ, _value in [
    ("duration_s-1e300", "duration_s", 0, "1.0e300"),
    ("duration_s-inf", "duration_s", 0, ".inf"),
    ("duration_s-negative", "duration_s", 0, "-1.0"),
    ("duration_s-zero", "duration_s", 0, "0.0"),
    ("seed-negative", "seed", 0, "-1"),
    ("seed-2e20", "seed", 0, "99999999999999999999"),
    ("orbit.altitude_km-1e300", "altitude_km", 0, "1.0e300"),
    ("orbit.altitude_km-negative", "altitude_km", 0, "-5.0"),
    ("plant.inertia_kg_m2-1e300", "inertia_kg_m2", 0, "[1.0e300, 1.0e300, 1.0e300]"),
    ("plant.inertia_kg_m2-negative", "inertia_kg_m2", 0, "[-1.0, 1.0, 1.0]"),
    ("plant.inertia_kg_m2-triangle", "inertia_kg_m2", 0, "[1.0, 1.0, 100.0]"),
    ("plant.initial_rate_deg_per_s-1e300", "initial_rate_deg_per_s", 0, "[1.0e300, 0.0, 0.0]"),
    ("plant.disturbance_torque_N_m-1e300", "disturbance_torque_N_m", 0, "[1.0e300, 0.0, 0.0]"),
    ("sensors.gyro.arw_deg_per_rt_h-1e300", "arw_deg_per_rt_h", 0, "1.0e300"),
    ("sensors.gyro.rrw_deg_per_h15-1e300", "rrw_deg_per_h15", 0, "1.0e300"),
    ("sensors.gyro.arw_deg_per_rt_h-negative", "arw_deg_per_rt_h", 0, "-1.0"),
    ("sensors.gyro.sample_rate_hz-1e300", "sample_rate_hz", 0, "1.0e300"),
    ("sensors.gyro.period_s-zero", "period_s", 0, "0.0"),
    ("sensors.gyro.initial_bias_deg_per_h-1e300", "initial_bias_deg_per_h", 0, "[1.0e300, 0.0, 0.0]"),
    ("sensors.st1.sigma_boresight_arcsec-negative", "sigma_boresight_arcsec", 0, "-5.0"),
    ("sensors.st1.sigma_boresight_arcsec-1e300", "sigma_boresight_arcsec", 0, "1.0e300"),
    ("sensors.st1.mounting-nan", "mounting", 0, "!PaperS3Eq7Mounting {psi_phi_theta_deg: [.nan, 45.0, -90.0]}"),
    ("sensors.st1.mounting-scalar", "mounting", 0, "5"),
    ("estimators.single.period_s-negative", "period_s", 2, "-1.0"),
    ("estimators.single.initial_attitude_sigma_deg-1e300", "initial_attitude_sigma_deg", 0, "1.0e300"),
    ("scoring.score_from_s-after-end", "score_from_s", 0, "10.0"),
    ("scoring.convergence_threshold_deg-zero", "convergence_threshold_deg", 0, "0.0"),
]:
    _needle = "psi_phi_theta_deg" if _label == "sensors.st1.mounting-nan" else _key
    _check_yaml(f"yaml-range-{_label}", _set_value(BASE, _key, _occ, _value), (_needle,))

# ---- YAML files: sections, unknown keys at nested levels, duplicates, references ---------------
_check_yaml(
    "yaml-section-simulation-scalar", re.sub(r"simulation:\n(  .*\n)+", "simulation: 5\n", BASE), ("simulation",)
)
_check_yaml("yaml-section-orbit-list", re.sub(r"orbit:\n(  .*\n)+", "orbit: [1, 2]\n", BASE), ("orbit",))
_check_yaml("yaml-section-plant-scalar", re.sub(r"plant: !RigidBodyConfig\n(  .*\n)+", "plant: 5\n", BASE), ("plant",))
_check_yaml("yaml-section-sensors-scalar", re.sub(r"sensors:\n(- .*\n|  .*\n)+", "sensors: 5\n", BASE), ("sensors",))
_check_yaml(
    "yaml-section-sensors-mapping", re.sub(r"sensors:\n(- .*\n|  .*\n)+", "sensors: {gyro: 1}\n", BASE), ("sensors",)
)
_check_yaml(
    "yaml-section-sensors-list-of-numbers",
    re.sub(r"sensors:\n(- .*\n|  .*\n)+", "sensors: [5, 6]\n", BASE),
    ("sensors",),
)
_check_yaml("yaml-section-sensors-missing", re.sub(r"sensors:\n(- .*\n|  .*\n)+", "", BASE), ("gyro",))
_check_yaml(
    "yaml-section-estimators-empty", re.sub(r"estimators:\n(- .*\n|  .*\n)+", "estimators:\n", BASE), ("estimators",)
)
_check_yaml(
    "yaml-section-estimators-scalar", re.sub(r"estimators:\n(- .*\n|  .*\n)+", "estimators: 5\n", BASE), ("estimators",)
)
_check_yaml("yaml-section-scoring-list", re.sub(r"scoring:\n(  .*\n)+", "scoring: [1]\n", BASE), ("scoring",))
_check_yaml("yaml-unknown-top-level", BASE + "bogus_top: 1\n", ("bogus_top",))
_check_yaml(
    "yaml-unknown-in-simulation",
    _sub(BASE, "simulation:\n", "simulation:\n  bogus_sim: 1\n"),
    ("simulation", "bogus_sim"),
)
_check_yaml("yaml-unknown-in-orbit", _sub(BASE, "orbit:\n", "orbit:\n  bogus_orbit: 1\n"), ("orbit", "bogus_orbit"))
_check_yaml(
    "yaml-unknown-in-plant",
    _sub(BASE, "plant: !RigidBodyConfig\n", "plant: !RigidBodyConfig\n  bogus_plant: 1\n"),
    ("plant", "bogus_plant"),
)
_check_yaml(
    "yaml-unknown-in-gyro", _sub(BASE, "  name: gyro\n", "  name: gyro\n  bogus_gyro: 1\n"), ("sensors", "bogus_gyro")
)
_check_yaml(
    "yaml-unknown-in-mounting",
    _sub(
        BASE, "{psi_phi_theta_deg: [-90.0, 45.0, -90.0]}", "{psi_phi_theta_deg: [-90.0, 45.0, -90.0], bogus_mount: 1}"
    ),
    ("mounting", "bogus_mount"),
)
_check_yaml(
    "yaml-unknown-in-estimator",
    _sub(BASE, "  name: single\n", "  name: single\n  bogus_est: 1\n"),
    ("estimators", "bogus_est"),
)
_check_yaml(
    "yaml-unknown-in-scoring", _sub(BASE, "scoring:\n", "scoring:\n  bogus_score: 1\n"), ("scoring", "bogus_score")
)
_check_yaml("yaml-unknown-non-string-key", BASE + "[1, 2]: 3\n", ("s.yaml",))
_check_yaml("yaml-unknown-null-key", BASE + "~: 3\n", ("s.yaml",))
_check_yaml("yaml-duplicate-top-level", BASE + "duration_s: 3.0\n", ("duration_s",))
_check_yaml(
    "yaml-duplicate-in-plant",
    _sub(
        BASE,
        "  inertia_kg_m2: [0.042, 0.042, 0.0067]\n",
        "  inertia_kg_m2: [0.042, 0.042, 0.0067]\n  inertia_kg_m2: [1.0, 1.0, 1.0]\n",
    ),
    ("inertia_kg_m2",),
)
_check_yaml(
    "yaml-duplicate-in-gyro",
    _sub(BASE, "  arw_deg_per_rt_h: 0.56\n", "  arw_deg_per_rt_h: 0.56\n  arw_deg_per_rt_h: 0.0\n"),
    ("arw_deg_per_rt_h",),
)
_check_yaml("yaml-duplicate-sensor-names", _sub(BASE, "  name: st1\n", "  name: gyro\n"), ("name",))
_check_yaml("yaml-duplicate-estimator-sensor-name", _sub(BASE, "  name: single\n", "  name: st1\n"), ("name",))
_check_yaml("yaml-reference-unknown-gyro", _sub(BASE, "  gyro: gyro\n", "  gyro: no_such_gyro\n"), ("no_such_gyro",))
_check_yaml(
    "yaml-reference-tracker-is-gyro",
    _sub(BASE, "  star_trackers: [st1]\n", "  star_trackers: [gyro]\n"),
    ("star_trackers",),
)
_check_yaml(
    "yaml-plugins-missing-module",
    _sub(BASE, "seed: 1\n", "seed: 1\nplugins: [no_such_plugin_xyz]\n"),
    ("no_such_plugin_xyz",),
)
_check_yaml("yaml-plugins-path-like", _sub(BASE, "seed: 1\n", "seed: 1\nplugins: ['../../evil']\n"), ("evil",))
_check_yaml("yaml-plugins-not-a-list", _sub(BASE, "seed: 1\n", "seed: 1\nplugins: 5\n"), ("plugins",))
_check_yaml("yaml-plugins-empty-name", _sub(BASE, "seed: 1\n", "seed: 1\nplugins: ['']\n"), ("plugins",))

# ---- YAML files through `run` (the same layer; refused before any simulation) ------------------
for _id, _text, _needles in [
    ("syntax", "name: x\nduration_s: [1, 2\n", ("s.yaml",)),
    ("python-tag", _set_value(BASE, "name", 0, f'!!python/object/apply:os.system ["{_PWN}"]'), ("s.yaml",)),
    ("foo-tag", _set_value(BASE, "duration_s", 0, "!foo 20"), ("s.yaml",)),
    ("bomb", _sub(BASE, "seed: 1\n", f"seed: 1\nplugins: {BOMB}\n"), ("s.yaml",)),
    ("2MiB", BASE + ("# " + "x" * 98 + "\n") * (2 * 2**20 // 100 + 1), ("s.yaml",)),
    ("binary", b"\x89PNG\r\n\x1a\n" + bytes(range(256)), ("s.yaml",)),
    ("latin1", _set_value(BASE, "description", 0, "café").encode("latin-1"), ("s.yaml",)),
    ("duration-five", _set_value(BASE, "duration_s", 0, "five"), ("duration_s",)),
    ("seed-one", _set_value(BASE, "seed", 0, "one"), ("seed",)),
    ("inertia-string", _set_value(BASE, "inertia_kg_m2", 0, "heavy"), ("inertia_kg_m2",)),
    ("nested-unknown", _sub(BASE, "  name: gyro\n", "  name: gyro\n  bogus_gyro: 1\n"), ("bogus_gyro",)),
    ("star-trackers-duplicate", _set_value(BASE, "star_trackers", 0, "[st1, st1]"), ("star_trackers",)),
    ("altitude-1e300", _set_value(BASE, "altitude_km", 0, "1.0e300"), ("altitude_km",)),
    ("estimators-empty", re.sub(r"estimators:\n(- .*\n|  .*\n)+", "estimators:\n", BASE), ("estimators",)),
]:
    case(
        f"run-yaml-{_id}",
        "run",
        "s.yaml",
        "--out",
        "r",
        "--no-figures",
        "--quiet",
        needles=_needles,
        files={"s.yaml": _text},
        max_s=(3.0 if _id in ("bomb", "2MiB") else None),
    )

# ---- --set strings (on the shipped single-tracker scenario) ------------------------------------
for _id, _setting, _needles in [
    ("no-equals", "duration_s", ("duration_s",)),
    ("empty-path", "=5", ("--set",)),
    ("empty-string", "", ("--set",)),
    ("dot-path", ".duration_s=5", ("--set",)),
    ("double-dot-path", "sensors..period_s=1", ("--set",)),
    ("yaml-open-bracket", "duration_s=[", ("--set",)),
    ("yaml-open-brace", "duration_s={", ("--set",)),
    ("yaml-close-bracket", "duration_s=]", ("--set",)),
    ("yaml-unterminated-quote", 'duration_s="abc', ("--set",)),
    ("yaml-undefined-alias", "duration_s=*nope", ("--set",)),
    ("yaml-two-documents", "duration_s=1\n---\n2", ("--set",)),
    ("yaml-python-tag", 'duration_s=!!python/object/apply:os.system ["touch @ROOT@/PWNED"]', ("duration_s",)),
    ("yaml-python-name-tag", "duration_s=!!python/name:os.system", ("duration_s",)),
    ("yaml-foo-tag", "duration_s=!foo 20", ("duration_s",)),
    ("yaml-bomb", f"description={BOMB}", ("description",)),
    ("yaml-recursive-alias", "description=&r [*r]", ("description",)),
    ("yaml-deep-nesting", "description=" + _nested_lists(10_000), ("description",)),
    ("yaml-nul", "name=a\x00b", ("name",)),
    ("duration-five", "duration_s=five", ("duration_s",)),
    ("duration-nan", "duration_s=nan", ("duration_s",)),
    ("duration-dot-nan", "duration_s=.nan", ("duration_s",)),
    ("duration-inf", "duration_s=inf", ("duration_s",)),
    ("duration-minus-inf", "duration_s=-.inf", ("duration_s",)),
    ("duration-1e300", "duration_s=1e300", ("duration_s",)),
    ("duration-negative", "duration_s=-1", ("duration_s",)),
    ("duration-zero", "duration_s=0", ("duration_s",)),
    ("duration-bool", "duration_s=true", ("duration_s",)),
    ("duration-null", "duration_s=null", ("duration_s",)),
    ("duration-empty", "duration_s=", ("duration_s",)),
    ("duration-list", "duration_s=[1, 2]", ("duration_s",)),
    ("duration-mapping", "duration_s={a: 1}", ("duration_s",)),
    ("duration-5000-digits", "duration_s=" + "9" * 5000, ("duration_s",)),
    ("duration-equals-in-value", "duration_s==5", ("duration_s",)),
    ("duration-through-scalar", "duration_s.x=1", ("duration_s",)),
    ("seed-one", "seed=one", ("seed",)),
    ("seed-float", "seed=1.5", ("seed",)),
    ("seed-null", "seed=null", ("seed",)),
    ("seed-negative", "seed=-1", ("seed",)),
    ("seed-2-to-32", "seed=4294967296", ("seed",)),
    ("seed-5000-digits", "seed=" + "9" * 5000, ("seed",)),
    ("name-null", "name=null", ("name",)),
    ("name-empty", "name=", ("name",)),
    ("name-empty-quoted", "name=''", ("name",)),
    ("name-list", "name=[a, b]", ("name",)),
    ("name-mapping", "name={a: 1}", ("name",)),
    ("description-mapping", "description={a: 1}", ("description",)),
    ("plugins-missing-module", "plugins=[no_such_plugin_xyz]", ("no_such_plugin_xyz",)),
    ("plugins-scalar", "plugins=5", ("plugins",)),
    ("orbit-altitude-1e300", "orbit.altitude_km=1.0e300", ("orbit.altitude_km",)),
    ("orbit-altitude-nan", "orbit.altitude_km=nan", ("altitude_km",)),
    ("orbit-altitude-inf", "orbit.altitude_km=.inf", ("altitude_km",)),
    ("orbit-altitude-negative", "orbit.altitude_km=-1", ("altitude_km",)),
    ("orbit-inclination-1e300", "orbit.inclination_deg=1e300", ("inclination_deg",)),
    ("orbit-scalar", "orbit=5", ("orbit",)),
    ("orbit-unknown-field", "orbit.bogus_orbit=1", ("bogus_orbit",)),
    ("simulation-scheme-unknown", "simulation.integration_scheme=rk99", ("integration_scheme",)),
    ("simulation-scheme-null", "simulation.integration_scheme=null", ("integration_scheme",)),
    ("simulation-error-control-maybe", "simulation.use_error_control=maybe", ("use_error_control",)),
    ("simulation-max-step-zero", "simulation.max_step_size_s=0", ("max_step_size_s",)),
    ("simulation-scalar", "simulation=5", ("simulation",)),
    ("plant-mapping-unknown-field", "plant={bogus_plant: 1}", ("bogus_plant",)),
    ("plant-scalar", "plant=5", ("plant",)),
    ("plant-null", "plant=null", ("plant",)),
    ("plant-inertia-string", "plant.inertia_kg_m2=heavy", ("inertia_kg_m2",)),
    ("plant-inertia-short", "plant.inertia_kg_m2=[1, 2]", ("inertia_kg_m2",)),
    ("plant-inertia-1e300", "plant.inertia_kg_m2=[1e300, 1e300, 1e300]", ("inertia_kg_m2",)),
    ("plant-inertia-strings", "plant.inertia_kg_m2=[a, b, c]", ("inertia_kg_m2",)),
    ("plant-rate-1e300", "plant.initial_rate_deg_per_s=[1.0e300, 0, 0]", ("initial_rate_deg_per_s",)),
    ("plant-unknown-field", "plant.bogus_plant=1", ("bogus_plant",)),
    ("plant-path-through-list", "plant.inertia_kg_m2.bogus=1", ("inertia_kg_m2",)),
    ("gyro-arw-1e300", "sensors.gyro.arw_deg_per_rt_h=1e300", ("arw_deg_per_rt_h",)),
    ("gyro-rrw-1e300", "sensors.gyro.rrw_deg_per_h15=1e300", ("rrw_deg_per_h15",)),
    ("gyro-arw-negative", "sensors.gyro.arw_deg_per_rt_h=-1", ("arw_deg_per_rt_h",)),
    ("gyro-arw-nan", "sensors.gyro.arw_deg_per_rt_h=.nan", ("arw_deg_per_rt_h",)),
    ("gyro-arw-inf", "sensors.gyro.arw_deg_per_rt_h=.inf", ("arw_deg_per_rt_h",)),
    ("gyro-sample-rate-1e300", "sensors.gyro.sample_rate_hz=1e300", ("sample_rate_hz",)),
    ("gyro-period-zero", "sensors.gyro.period_s=0", ("period_s",)),
    ("gyro-null", "sensors.gyro=null", ("sensors.gyro",)),
    ("gyro-renamed-to-st1", "sensors.gyro.name=st1", ("name",)),
    ("st1-renamed-empty", "sensors.st1.name=", ("name",)),
    ("st1-mode-banana", "sensors.st1.mode=banana", ("mode",)),
    ("st1-unknown-field", "sensors.st1.bogus_st=1", ("bogus_st",)),
    ("sensors-index-out-of-range", "sensors.5.period_s=1", ("sensors.5",)),
    ("sensors-index-negative", "sensors.-1.period_s=1", ("sensors",)),
    ("sensors-index-huge", "sensors.99999999999999999999.period_s=1", ("sensors",)),
    ("sensors-unknown-name", "sensors.no_such_sensor.period_s=1", ("no_such_sensor",)),
    ("sensors-homoglyph-name", "sensors.gyrо.period_s=1", ("sensors",)),  # Cyrillic "о"
    ("sensors-scalar", "sensors=5", ("sensors",)),
    ("sensors-empty-list", "sensors=[]", ("gyro",)),
    ("estimators-null", "estimators=null", ("estimators",)),
    ("estimators-scalar", "estimators=5", ("estimators",)),
    ("estimators-index-out-of-range", "estimators.9.period_s=1", ("estimators.9",)),
    ("estimators-single-null", "estimators.single=null", ("estimators.single",)),
    ("mekf-star-trackers-duplicate", "estimators.single.star_trackers=[st1, st1]", ("star_trackers",)),
    ("mekf-star-trackers-unknown", "estimators.single.star_trackers=[no_such_tracker]", ("no_such_tracker",)),
    ("mekf-star-trackers-scalar", "estimators.single.star_trackers=5", ("star_trackers",)),
    ("mekf-gyro-unknown", "estimators.single.gyro=no_such_gyro", ("no_such_gyro",)),
    ("mekf-period-negative", "estimators.single.period_s=-1", ("period_s",)),
    ("mekf-sigma-nan", "estimators.single.initial_attitude_sigma_deg=nan", ("initial_attitude_sigma_deg",)),
    ("mekf-unknown-field", "estimators.single.bogus_est=1", ("bogus_est",)),
    ("scoring-after-end", "scoring.score_from_s=1e9", ("score_from_s",)),
    ("scoring-list", "scoring=[]", ("scoring",)),
    ("unknown-top-level", "bogus_top=1", ("bogus_top",)),
    ("unicode-path", "näme=1", ("näme",)),
    ("rtl-override-value", "duration_s=\u202e5", ("duration_s",)),
    ("surrogate-escape-value", "duration_s=\udcff", ("duration_s",)),
    ("huge-path-100k", "p" * 100_000 + "=1", ("--set",)),
]:
    _check_set(f"set-{_id}", _setting, _needles, max_s=(3.0 if "bomb" in _id or "deep" in _id else None))
_check_set(
    "set-fault-outlier-rate-1e300",
    "sensors.gyro_faults.outlier_rate_deg_per_s=1.0e300",
    ("outlier_rate_deg_per_s",),
    scenario="fault_campaign",
)
_check_set(
    "set-num-particles-1e9",
    "estimators.gyroless_pf.num_particles=1000000000",
    ("num_particles",),
    scenario="s0_gyroless_pf",
    max_s=3.0,
)
_check_set(
    "set-num-particles-zero", "estimators.gyroless_pf.num_particles=0", ("num_particles",), scenario="s0_gyroless_pf"
)
_check_set(
    "set-num-particles-float", "estimators.gyroless_pf.num_particles=2.5", ("num_particles",), scenario="s0_gyroless_pf"
)
_check_set(
    "set-num-particles-hex-huge",
    "estimators.gyroless_pf.num_particles=0x7fffffffffffffff",
    ("num_particles",),
    scenario="s0_gyroless_pf",
    max_s=3.0,
)
case("set-missing-value", "check", S, "--set", needles=("--set",))
# A mapping for a section sets (or replaces) its fields: valid or refused, never a traceback.
_check_set("set-plant-mapping-valid-fields", "plant={inertia_kg_m2: [1, 1, 1]}", (), code=(0, 2))
case(
    "set-several-last-bad",
    "check",
    S,
    "--set",
    "sensors.st1.sigma_boresight_arcsec=20",
    "--set",
    "seed=one",
    needles=("seed",),
)
# The same through `run` (refused before any simulation; never a result folder)
for _id, _setting, _needles in [
    ("open-bracket", "duration_s=[", ("--set",)),
    ("python-tag", "duration_s=!!python/object/apply:os.system [x]", ("duration_s",)),
    ("foo-tag", "duration_s=!foo 20", ("duration_s",)),
    ("name-null", "name=null", ("name",)),
    ("altitude-1e300", "orbit.altitude_km=1.0e300", ("orbit.altitude_km",)),
    ("arw-1e300", "sensors.gyro.arw_deg_per_rt_h=1e300", ("arw_deg_per_rt_h",)),
    ("rrw-1e300", "sensors.gyro.rrw_deg_per_h15=1e300", ("rrw_deg_per_h15",)),
    ("plant-mapping-unknown-field", "plant={bogus_plant: 1}", ("bogus_plant",)),
    ("star-trackers-duplicate", "estimators.single.star_trackers=[st1, st1]", ("star_trackers",)),
]:
    case(f"run-set-{_id}", "run", S, "--set", _setting, "--out", "r", "--no-figures", "--quiet", needles=_needles)
# ... and through `montecarlo` / `compare` (the same layer before any campaign folder exists)
for _cmd in ("montecarlo", "compare"):
    for _id, _text, _needles in [
        ("python-tag", _set_value(BASE, "name", 0, f'!!python/object/apply:os.system ["{_PWN}"]'), ("s.yaml",)),
        ("bomb", _sub(BASE, "seed: 1\n", f"seed: 1\nplugins: {BOMB}\n"), ("s.yaml",)),
        ("nested-unknown", _sub(BASE, "  name: gyro\n", "  name: gyro\n  bogus_gyro: 1\n"), ("bogus_gyro",)),
    ]:
        case(
            f"{_cmd}-yaml-{_id}",
            _cmd,
            "s.yaml",
            "--runs",
            "1",
            "--workers",
            "1",
            "--quiet",
            "--out",
            "camp_new",
            needles=_needles,
            files={"s.yaml": _text},
            max_s=(3.0 if _id == "bomb" else None),
        )
case("check-seed-text", "check", S, "--seed", "abc", needles=("--seed",))
case("check-seed-negative", "check", S, "--seed=-1", needles=("seed",))
case(
    "run-set-num-particles-1e9",
    "run",
    "s0_gyroless_pf",
    "--set",
    "estimators.gyroless_pf.num_particles=1000000000",
    "--out",
    "r",
    "--no-figures",
    "--quiet",
    needles=("num_particles",),
    max_s=3.0,
)

# ---- CLI options ---------------------------------------------------------------------------
_MC = ("montecarlo", S, *TINY_SET, "--quiet", "--out", "mcnew")
_CMP = ("compare", S, *TINY_SET, "--quiet", "--out", "cmpnew")
_MC_SCHED = (*_MC, "--runs", "1", "--connect-timeout", "2", "--scheduler")  # + an address
for _id, _argv, _needles in [
    ("no-arguments", (), ()),
    ("unknown-subcommand", ("frobnicate",), ("frobnicate",)),
    ("run-unknown-option", ("run", S, "--bogus-option"), ("--bogus-option",)),
    ("run-extra-positional", ("run", S, "zzz_extra"), ("zzz_extra",)),
    ("run-seed-text", ("run", S, "--seed", "abc"), ("--seed",)),
    ("run-seed-float", ("run", S, "--seed", "1.5"), ("--seed",)),
    ("run-seed-hex", ("run", S, "--seed", "0x10"), ("--seed",)),
    ("run-seed-empty", ("run", S, "--seed", ""), ("--seed",)),
    ("run-seed-missing-value", ("run", S, "--seed"), ("--seed",)),
    ("run-seed-negative", ("run", S, "--seed=-1"), ("seed",)),
    ("run-seed-2-to-32", ("run", S, "--seed", str(2**32)), ("seed",)),
    ("run-seed-1e30", ("run", S, "--seed", "1" + "0" * 30), ("seed",)),
    ("run-seed-5000-digits", ("run", S, "--seed", "9" * 5000), ("seed",)),
    ("run-set-missing-value", ("run", S, "--set"), ("--set",)),
    ("run-out-missing-value", ("run", S, "--out"), ("--out",)),
    ("run-scenario-unknown", ("run", "no_such_scenario"), ("no_such_scenario",)),
    ("run-scenario-huge-name", ("run", "n" * 100_000), ("scenario",)),
    ("run-scenario-folder", ("run", "thesis"), ("thesis",)),
    ("run-scenario-dev-null", ("run", "/dev/null"), ("/dev/null",)),
    ("check-unknown-option", ("check", S, "--bogus-option"), ("--bogus-option",)),
    ("check-scenario-unknown", ("check", "no_such_scenario"), ("no_such_scenario",)),
    ("score-no-argument", ("score",), ("OUT_DIR",)),
    ("score-unknown-option", ("score", "thesis", "--bogus-option"), ("--bogus-option",)),
    ("list-extra-argument", ("list", "zzz_extra"), ("zzz_extra",)),
    ("montecarlo-runs-missing", ("montecarlo", S, "--workers", "1"), ("--runs",)),
    ("montecarlo-runs-zero", (*_MC, "--workers", "1", "--runs", "0"), ("--runs",)),
    ("montecarlo-runs-negative", (*_MC, "--workers", "1", "--runs", "-1"), ("--runs",)),
    ("montecarlo-runs-huge", (*_MC, "--workers", "1", "--runs", str(10**12)), ("--runs",)),
    ("montecarlo-runs-float", (*_MC, "--workers", "1", "--runs", "2.5"), ("--runs",)),
    ("montecarlo-runs-text", (*_MC, "--workers", "1", "--runs", "many"), ("--runs",)),
    (
        "montecarlo-first-seed-negative",
        (*_MC, "--workers", "1", "--runs", "1", "--first-seed", "-1"),
        ("--first-seed",),
    ),
    (
        "montecarlo-first-seed-2-to-32",
        (*_MC, "--workers", "1", "--runs", "1", "--first-seed", str(2**32)),
        ("--first-seed",),
    ),
    (
        "montecarlo-first-seed-overflow",
        (*_MC, "--workers", "1", "--runs", "2", "--first-seed", str(2**32 - 1)),
        ("--first-seed",),
    ),
    ("montecarlo-first-seed-text", (*_MC, "--workers", "1", "--runs", "1", "--first-seed", "one"), ("--first-seed",)),
    ("montecarlo-workers-zero", (*_MC, "--runs", "1", "--workers", "0"), ("--workers",)),
    ("montecarlo-workers-negative", (*_MC, "--runs", "1", "--workers", "-3"), ("--workers",)),
    ("montecarlo-workers-text", (*_MC, "--runs", "1", "--workers", "many"), ("--workers",)),
    (
        "montecarlo-workers-with-scheduler",
        (*_MC, "--runs", "1", "--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"),
        ("--workers",),
    ),
    ("montecarlo-scheduler-http", (*_MC_SCHED, "http://127.0.0.1:8787"), ("--scheduler",)),
    ("montecarlo-scheduler-https", (*_MC_SCHED, "https://example.invalid/"), ("--scheduler",)),
    ("montecarlo-scheduler-file-url", (*_MC_SCHED, "file:///etc/passwd"), ("--scheduler",)),
    ("montecarlo-scheduler-empty", (*_MC_SCHED, ""), ("--scheduler",)),
    ("montecarlo-scheduler-garbage", (*_MC_SCHED, "not an address"), ("--scheduler",)),
    ("montecarlo-scheduler-bad-port", (*_MC_SCHED, "tcp://127.0.0.1:notaport"), ("--scheduler",)),
    ("montecarlo-scheduler-port-99999", (*_MC_SCHED, "tcp://127.0.0.1:99999"), ("--scheduler",)),
    ("montecarlo-scheduler-huge", (*_MC_SCHED, "tcp://" + "a" * 100_000 + ":1"), ("--scheduler",)),
    (
        "montecarlo-connect-timeout-negative",
        (*_MC, "--runs", "1", "--scheduler", "tcp://127.0.0.1:1", "--connect-timeout", "-1"),
        ("--connect-timeout",),
    ),
    (
        "montecarlo-connect-timeout-nan",
        (*_MC, "--runs", "1", "--scheduler", "tcp://127.0.0.1:1", "--connect-timeout", "nan"),
        ("--connect-timeout",),
    ),
    (
        "montecarlo-connect-timeout-inf",
        (*_MC, "--runs", "1", "--scheduler", "tcp://127.0.0.1:1", "--connect-timeout", "inf"),
        ("--connect-timeout",),
    ),
    (
        "montecarlo-connect-timeout-1e400",
        (*_MC, "--runs", "1", "--scheduler", "tcp://127.0.0.1:1", "--connect-timeout", "1e400"),
        ("--connect-timeout",),
    ),
    (
        "montecarlo-connect-timeout-text",
        (*_MC, "--runs", "1", "--scheduler", "tcp://127.0.0.1:1", "--connect-timeout", "soon"),
        ("--connect-timeout",),
    ),
    (
        "montecarlo-estimators-unknown",
        (*_MC, "--workers", "1", "--runs", "1", "--estimators", "no_such_est"),
        ("no_such_est",),
    ),
    ("montecarlo-estimators-empty", (*_MC, "--workers", "1", "--runs", "1", "--estimators", ","), ("--estimators",)),
    (
        "montecarlo-estimators-duplicate",
        (*_MC, "--workers", "1", "--runs", "1", "--estimators", "single,single"),
        ("--estimators",),
    ),
    (
        "montecarlo-estimators-huge",
        (*_MC, "--workers", "1", "--runs", "1", "--estimators", "e" * 100_000),
        ("--estimators",),
    ),
    (
        "montecarlo-scenario-unknown",
        ("montecarlo", "no_such_scenario", "--runs", "1", "--workers", "1"),
        ("no_such_scenario",),
    ),
    ("compare-no-scenario", ("compare", "--runs", "1", "--workers", "1"), ("SCENARIO",)),
    ("compare-duplicate-scenario", ("compare", S, S, "--runs", "1", "--workers", "1"), (S,)),
    (
        "compare-unknown-scenario",
        ("compare", "no_such_scenario", "--runs", "1", "--workers", "1"),
        ("no_such_scenario",),
    ),
    (
        "compare-estimators-unknown-source",
        (*_CMP, "--runs", "1", "--workers", "1", "--estimators", "no_such_scenario:single"),
        ("no_such_scenario",),
    ),
    ("compare-runs-zero", (*_CMP, "--runs", "0", "--workers", "1"), ("--runs",)),
    (
        "compare-scheduler-http",
        (*_CMP, "--runs", "1", "--connect-timeout", "2", "--scheduler", "http://127.0.0.1:8787"),
        ("--scheduler",),
    ),
    ("debug-run-user-error", ("run", "no_such_scenario", "--debug"), ("no_such_scenario",)),
    ("debug-check-user-error", ("check", "no_such_scenario", "--debug"), ("no_such_scenario",)),
    ("debug-score-user-error", ("score", "no_such_folder", "--debug"), ("no_such_folder",)),
    ("debug-montecarlo-user-error", (*_MC, "--workers", "1", "--runs", "0", "--debug"), ("--runs",)),
    ("debug-compare-user-error", (*_CMP, "--workers", "1", "--runs", "0", "--debug"), ("--runs",)),
]:
    case(f"opt-{_id}", *_argv, needles=_needles)
case("opt-debug-list-ok", "list", "--debug", code=0)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


case(
    "opt-montecarlo-scheduler-nothing-listening",
    *_MC,
    "--runs",
    "1",
    "--scheduler",
    f"tcp://127.0.0.1:{_closed_port()}",
    "--connect-timeout",
    "2",
    needles=("--scheduler",),
    max_s=30.0,
)


# ---- result folders read by `score` -------------------------------------------------------------
def _copy_run(ctx: Ctx, dest: str = "res") -> str:
    path = ctx.path(dest)
    shutil.copytree(ctx.results["run"], path)
    return path


def _copy_campaign(ctx: Ctx, dest: str = "mcres") -> str:
    path = ctx.path(dest)
    shutil.copytree(ctx.results["campaign"], path)
    return path


def _rewrite_npz(path: str, edit: Callable[[dict], dict], **savez_kw) -> None:
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays = edit(arrays)
    with open(path, "wb") as f:
        np.savez(f, **arrays, **savez_kw)


class _Payload:
    """Unpickling this creates the marker file (``open(marker, "w")``)."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _pickled(ctx: Ctx) -> np.ndarray:
    return np.array([_Payload(ctx.path("UNPICKLED")), 1], dtype=object)


def _first_key(arrays: dict) -> str:
    return sorted(arrays)[0]


def _npy_claiming(shape) -> bytes:
    """A .npy whose header claims ``shape`` (float64) followed by 8 bytes of data."""
    header = repr({"descr": "<f8", "fortran_order": False, "shape": tuple(shape)}).encode()
    header += b" " * ((64 - (10 + len(header) + 1) % 64) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + bytes(8)


def _npz_with_huge_header(ctx: Ctx) -> None:
    path = os.path.join(_copy_run(ctx), "log.npz")
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    key = _first_key(arrays)
    with zipfile.ZipFile(path, "w") as z:
        for k, a in arrays.items():
            buf = io.BytesIO()
            np.save(buf, a)
            z.writestr(f"{k}.npy", _npy_claiming((10**12,)) if k == key else buf.getvalue())


def _plugin_module(ctx: Ctx, folder: str, module: str) -> None:
    """``folder/module.py`` that creates ``PLUGIN_WAS_IMPORTED`` in the test's folder when
    imported; the folder is put on ``sys.path`` (as the current folder is for ``python -m``)."""
    with open(os.path.join(folder, f"{module}.py"), "w") as f:
        f.write(f"open({ctx.path('PLUGIN_WAS_IMPORTED')!r}, 'w').write('imported')\n")
    ctx.monkeypatch.syspath_prepend(folder)
    ctx.cleanup.append(lambda: sys.modules.pop(module, None))


def _name_plugin_in_config(path: str, module: str) -> None:
    """``plugins: [module]`` in the config.yaml at ``path`` (replacing its ``plugins:`` line)."""
    with open(path) as f:
        text = f.read()
    with open(path, "w") as f:
        f.write(
            re.sub(r"^plugins:.*$", f"plugins: [{module}]", text, count=1, flags=re.M)
            if re.search(r"^plugins:", text, re.M)
            else f"plugins: [{module}]\n" + text
        )


def _config_with_plugin(ctx: Ctx, folder: str, module: str) -> None:
    _plugin_module(ctx, folder, module)
    _name_plugin_in_config(os.path.join(folder, "config.yaml"), module)


def _no_marker(*names):
    def expect(ctx: Ctx, c: Call) -> list[str]:
        return [f"{n} exists: the payload ran" for n in names if os.path.lexists(ctx.path(n))]

    return expect


def _edit_config(old_new: Callable[[str], str]):
    def setup(ctx: Ctx) -> None:
        path = os.path.join(_copy_run(ctx), "config.yaml")
        with open(path, encoding="utf-8") as f:
            text = f.read()
        data = old_new(text)
        with open(path, "wb") as f:
            f.write(data if isinstance(data, bytes) else data.encode())

    return setup


def _remove(rel):
    def setup(ctx: Ctx) -> None:
        _copy_run(ctx)
        target = ctx.path("res", rel)
        shutil.rmtree(target) if os.path.isdir(target) else os.remove(target)

    return setup


def _replace_file(rel, data: bytes | Callable[[bytes], bytes], folder=_copy_run):
    def setup(ctx: Ctx) -> None:
        base = folder(ctx)
        path = os.path.join(base, rel)
        old = open(path, "rb").read() if os.path.isfile(path) else b""
        with open(path, "wb") as f:
            f.write(data(old) if callable(data) else data)

    return setup


def _npz_edit(edit: Callable[[Ctx, dict], dict], rel="log.npz", folder=_copy_run):
    def setup(ctx: Ctx) -> None:
        base = folder(ctx)
        _rewrite_npz(os.path.join(base, rel), lambda arrays: edit(ctx, arrays))

    return setup


def _log_is_folder(ctx: Ctx) -> None:
    _copy_run(ctx)
    os.remove(ctx.path("res", "log.npz"))
    os.mkdir(ctx.path("res", "log.npz"))


def _drop_first(ctx, arrays):
    arrays.pop(_first_key(arrays))
    return arrays


def _first_pickled(ctx, arrays):
    arrays[_first_key(arrays)] = _pickled(ctx)
    return arrays


def _first_reshaped(ctx, arrays):
    arrays[_first_key(arrays)] = np.zeros((3, 5, 7))
    return arrays


def _first_strings(ctx, arrays):
    arrays[_first_key(arrays)] = np.array(["a", "b"])
    return arrays


def _extra_key(ctx, arrays):
    arrays["zz_extra_key"] = np.arange(3)
    return arrays


def _all_nan(ctx, arrays):
    return {k: (np.full(a.shape, np.nan) if a.dtype.kind == "f" else a) for k, a in arrays.items()}


_SCORE = ("score", "res")
for _id, _argv, _needles, _kw in [
    ("missing-folder", ("score", "no_such_folder"), ("no_such_folder",), {}),
    ("folder-is-a-file", ("score", "notes.txt"), ("notes.txt",), {}),
    ("empty-folder", ("score", "emptydir"), ("log.npz",), {"setup": lambda ctx: os.mkdir(ctx.path("emptydir"))}),
    ("user-folder", ("score", "thesis"), ("log.npz",), {}),
    ("campaign-folder", ("score", "mcres"), ("log.npz",), {"setup": _copy_campaign}),
    ("no-log", _SCORE, ("log.npz",), {"setup": _remove("log.npz")}),
    ("no-config", _SCORE, ("config.yaml",), {"setup": _remove("config.yaml")}),
    ("log-truncated", _SCORE, ("log.npz",), {"setup": _replace_file("log.npz", lambda b: b[: len(b) // 2])}),
    ("log-garbage", _SCORE, ("log.npz",), {"setup": _replace_file("log.npz", b"garbage" * 100)}),
    ("log-empty", _SCORE, ("log.npz",), {"setup": _replace_file("log.npz", b"")}),
    ("log-is-a-folder", _SCORE, ("log.npz",), {"setup": _log_is_folder}),
    (
        "log-zip-of-text",
        _SCORE,
        ("log.npz",),
        {"setup": _replace_file("log.npz", lambda b: _zip_bytes({"t.npy": b"not an array"}))},
    ),
    (
        "log-pickled-object-array",
        _SCORE,
        ("log.npz",),
        {"setup": _npz_edit(_first_pickled), "expect": _no_marker("UNPICKLED")},
    ),
    ("log-missing-array", _SCORE, ("log.npz",), {"setup": _npz_edit(_drop_first)}),
    ("log-array-wrong-shape", _SCORE, ("log.npz",), {"setup": _npz_edit(_first_reshaped)}),
    ("log-array-of-strings", _SCORE, ("log.npz",), {"setup": _npz_edit(_first_strings)}),
    ("log-header-claims-8TB", _SCORE, ("log.npz",), {"setup": _npz_with_huge_header, "max_s": 5.0}),
    (
        "config-python-tag",
        _SCORE,
        ("config.yaml",),
        {
            "setup": _edit_config(
                lambda t: re.sub(
                    r"^name:.*$", 'name: !!python/object/apply:os.system ["touch PWNED"]', t, count=1, flags=re.M
                )
            )
        },
    ),
    (
        "config-foo-tag",
        _SCORE,
        ("config.yaml",),
        {"setup": _edit_config(lambda t: re.sub(r"^duration_s:.*$", "duration_s: !foo 2", t, count=1, flags=re.M))},
    ),
    ("config-binary", _SCORE, ("config.yaml",), {"setup": _edit_config(lambda t: bytes(range(256)) * 8)}),
    (
        "config-latin1",
        _SCORE,
        ("config.yaml",),
        {"setup": _edit_config(lambda t: t.encode() + "# café\n".encode("latin-1"))},
    ),
    ("config-empty", _SCORE, ("config.yaml",), {"setup": _edit_config(lambda t: "")}),
    (
        "config-bomb",
        _SCORE,
        ("config.yaml",),
        {
            "setup": _edit_config(lambda t: re.sub(r"^plugins:.*$", f"plugins: {BOMB}", t, count=1, flags=re.M)),
            "max_s": 3.0,
        },
    ),
    (
        "config-2MiB",
        _SCORE,
        ("config.yaml",),
        {"setup": _edit_config(lambda t: t + "#" * (2 * 2**20) + "\n"), "max_s": 2.0},
    ),
    ("config-unknown-field", _SCORE, ("config.yaml",), {"setup": _edit_config(lambda t: t + "bogus_top: 1\n")}),
    (
        "config-duration-five",
        _SCORE,
        ("config.yaml",),
        {"setup": _edit_config(lambda t: re.sub(r"^duration_s:.*$", "duration_s: five", t, count=1, flags=re.M))},
    ),
    (
        "config-plugin-missing-module",
        _SCORE,
        ("no_such_plugin_xyz",),
        {
            "setup": _edit_config(
                lambda t: "plugins: [no_such_plugin_xyz]\n" + re.sub(r"^plugins:.*\n", "", t, flags=re.M)
            )
        },
    ),
    (
        "config-plugin-in-the-folder",
        _SCORE,
        ("evil_plugin_score", "--allow-plugins"),
        {
            "setup": lambda ctx: _config_with_plugin(ctx, _copy_run(ctx), "evil_plugin_score"),
            "expect": _no_marker("PLUGIN_WAS_IMPORTED"),
        },
    ),
    ("out-under-a-file", (*_SCORE, "--out", "notes.txt/m.json"), ("m.json",), {"setup": _copy_run}),
    ("out-is-a-folder", (*_SCORE, "--out", "thesis"), ("thesis",), {"setup": _copy_run}),
    ("out-empty", (*_SCORE, "--out", ""), ("--out",), {"setup": _copy_run}),
]:
    case(f"score-{_id}", *_argv, needles=_needles, **_kw)
# Not refusals, but nothing may break either: an extra array is ignored or refused, NaN estimates
# are scored or refused - never a traceback, never a file outside the folder.
case("score-log-extra-array", *_SCORE, needles=(), code=(0, 2), setup=_npz_edit(_extra_key), changes=("res",))
case("score-log-all-nan", *_SCORE, needles=(), code=(0, 2), setup=_npz_edit(_all_nan), changes=("res",))


def _zip_bytes(members: dict) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return buf.getvalue()


# ---- campaign folders read by `montecarlo --resume` ---------------------------------------------
_RESUME = ("montecarlo", S, *MC_TINY, "--out", "mcres", "--resume")


def _campaign_edit(rel, data):
    return _replace_file(rel, data, folder=_copy_campaign)


def _campaign_npz(edit):
    return _npz_edit(edit, rel=os.path.join("runs", "seed_1.npz"), folder=_copy_campaign)


def _campaign_config_plugin(ctx: Ctx) -> None:
    folder = _copy_campaign(ctx)
    _config_with_plugin(ctx, folder, "evil_plugin_resume")


def _runs_is_file(ctx: Ctx) -> None:
    folder = _copy_campaign(ctx)
    shutil.rmtree(os.path.join(folder, "runs"))
    with open(os.path.join(folder, "runs"), "w") as f:
        f.write("not a folder\n")


def _run_file_is_folder(ctx: Ctx) -> None:
    folder = _copy_campaign(ctx)
    os.remove(os.path.join(folder, "runs", "seed_1.npz"))
    os.mkdir(os.path.join(folder, "runs", "seed_1.npz"))


def _huge_failed_txt(ctx: Ctx) -> None:
    folder = _copy_campaign(ctx)
    os.remove(os.path.join(folder, "runs", "seed_1.npz"))
    with open(os.path.join(folder, "runs", "seed_1.failed.txt"), "w") as f:
        f.write("truth went non-finite " + "x" * 100_000 + "\n")


for _id, _setup, _needles, _code, _kw in [
    ("campaign-json-list", _campaign_edit("campaign.json", b"[1, 2]\n"), ("mcres",), 2, {}),
    ("campaign-json-null", _campaign_edit("campaign.json", b"null\n"), ("mcres",), 2, {}),
    ("campaign-json-garbage", _campaign_edit("campaign.json", b"{not json"), ("mcres",), 2, {}),
    ("campaign-json-binary", _campaign_edit("campaign.json", bytes(range(256))), ("mcres",), 2, {}),
    (
        "config-edited",
        _campaign_edit("config.yaml", lambda b: b.replace(b"duration_s: 2.0", b"duration_s: 3.0")),
        ("mcres",),
        2,
        {},
    ),
    (
        "config-python-tag",
        _campaign_edit(
            "config.yaml",
            lambda b: re.sub(rb"(?m)^name:.*$", b'name: !!python/object/apply:os.system ["touch PWNED"]', b, count=1),
        ),
        ("mcres",),
        2,
        {},
    ),
    (
        "config-plugin-in-the-folder",
        _campaign_config_plugin,
        ("mcres",),
        2,
        {"expect": _no_marker("PLUGIN_WAS_IMPORTED")},
    ),
    ("runs-is-a-file", _runs_is_file, ("runs",), 2, {}),
    ("run-file-extra-array", _campaign_npz(_extra_key), ("seed_1",), (0, 2), {}),
    ("run-file-missing-array", _campaign_npz(_drop_first), ("seed_1",), (0, 2), {}),
    ("run-file-edited-array", _campaign_npz(_first_reshaped), ("seed_1",), (0, 2), {}),
    (
        "run-file-pickled-object-array",
        _campaign_npz(_first_pickled),
        ("seed_1",),
        (0, 2),
        {"expect": _no_marker("UNPICKLED")},
    ),
    (
        "run-file-truncated",
        _campaign_edit(os.path.join("runs", "seed_1.npz"), lambda b: b[: len(b) // 2]),
        ("seed_1",),
        (0, 2),
        {},
    ),
    ("run-file-is-a-folder", _run_file_is_folder, ("seed_1",), (0, 2), {}),
    ("failed-txt-100k-line", _huge_failed_txt, (), (0, 2), {}),
]:
    case(
        f"resume-{_id}",
        *_RESUME,
        needles=_needles,
        code=_code,
        setup=_setup,
        changes=(("mcres",) if _code != 2 else ()),
        **_kw,
    )
case(
    "resume-existing-campaign-without-resume",
    "montecarlo",
    S,
    *MC_TINY,
    "--out",
    "mcres",
    needles=("--resume",),
    setup=_copy_campaign,
)
case("resume-into-user-folder", "montecarlo", S, *MC_TINY, "--out", "thesis", "--resume", needles=("thesis",))


# ---- output folders and disks -------------------------------------------------------------------
def _mkdirs(*rels):
    def setup(ctx: Ctx) -> None:
        for rel in rels:
            os.makedirs(ctx.path(rel), exist_ok=True)

    return setup


def _home(with_file: bool = True, sub: str = "home"):
    def setup(ctx: Ctx) -> None:
        home = ctx.path(sub)
        os.makedirs(home, exist_ok=True)
        if with_file:
            with open(os.path.join(home, ".bashrc"), "w") as f:
                f.write("# a user's shell settings\n")
        os.makedirs(ctx.path("work"), exist_ok=True)
        ctx.monkeypatch.setenv("HOME", home)

    return setup


def _symlink(target_rel: str, link_rel: str):
    def setup(ctx: Ctx) -> None:
        os.symlink(ctx.path(target_rel), ctx.path(link_rel))

    return setup


def _ours_plus(extra: str | None):
    def setup(ctx: Ctx) -> None:
        _copy_run(ctx, "prev")
        if extra:
            with open(ctx.path("prev", extra), "w") as f:
                f.write("the user's own notes\n")

    return setup


def _foreign_manifest(ctx: Ctx) -> None:
    os.makedirs(ctx.path("fm"))
    for name, text in (("manifest.json", '{"files": "not ours"}'), ("data.csv", "1,2,3\n")):
        with open(ctx.path("fm", name), "w") as f:
            f.write(text)


def _full_disk(ctx: Ctx) -> None:
    """Every free-space query reports a full file system."""
    usage = shutil._ntuple_diskusage(total=10**12, used=10**12, free=0)  # type: ignore[attr-defined]
    ctx.monkeypatch.setattr(shutil, "disk_usage", lambda path: usage)
    real = os.statvfs

    def statvfs(path):
        s = real(path)
        return os.statvfs_result(
            (s.f_bsize, s.f_frsize, s.f_blocks, 0, 0, s.f_files, s.f_ffree, s.f_favail, s.f_flag, s.f_namemax)
        )

    ctx.monkeypatch.setattr(os, "statvfs", statvfs)


def _stale_staging(ctx: Ctx) -> None:
    for rel in (".rstale.writing-abcd1234", ".rstale.replaced-efgh5678/previous", ".other.writing-zz99yy88"):
        os.makedirs(ctx.path(rel))
        with open(ctx.path(rel, "metrics.json"), "w") as f:
            f.write("{}\n")


def _stale_gone(ctx: Ctx, c: Call) -> list[str]:
    left = [
        n
        for n in (".rstale.writing-abcd1234", ".rstale.replaced-efgh5678", ".other.writing-zz99yy88")
        if os.path.lexists(ctx.path(n))
    ]
    return [f"stale staging folders of ours left behind: {left}"] if left else []


def _lock(name: str, live: bool):
    def setup(ctx: Ctx) -> None:
        if live:
            child = subprocess.Popen(["sleep", "120"])
            ctx.cleanup.append(lambda: (child.kill(), child.wait()))
        else:
            child = subprocess.Popen(["true"])
            child.wait()
        with open(ctx.path(f".{name}.lock"), "w") as f:
            f.write(f"{child.pid} {socket.gethostname()}\n")

    return setup


def _lock_gone(name):
    def expect(ctx: Ctx, c: Call) -> list[str]:
        return [f".{name}.lock left behind"] if os.path.lexists(ctx.path(f".{name}.lock")) else []

    return expect


def _has_manifest(rel):
    def expect(ctx: Ctx, c: Call) -> list[str]:
        return [] if os.path.isfile(ctx.path(rel, "manifest.json")) else [f"{rel}/manifest.json was not written"]

    return expect


def _one_safe_folder(out_rel):
    """Exit 0: ``out_rel`` (the default ``out/``) holds exactly one new folder, named by one
    harmless path component."""

    def expect(ctx: Ctx, c: Call) -> list[str]:
        if c.code != 0:
            return []
        out = ctx.path(out_rel)
        names = os.listdir(out) if os.path.isdir(out) else []
        bad = [n for n in names if n.startswith(".") or len(n) > 255 or "\\" in n or "\x00" in n]
        return ([f"{out_rel}/ holds {names!r}, expected one result folder"] if len(names) != 1 else []) + (
            [f"unsafe output names {bad!r}"] if bad else []
        )

    return expect


for _id, _argv, _needles, _kw in [
    ("user-folder", ("--out", "thesis"), ("thesis",), {}),
    ("user-folder-trailing-slash", ("--out", "thesis/"), ("thesis",), {}),
    ("user-folder-dot-suffix", ("--out", "thesis/."), ("thesis",), {}),
    ("user-folder-dotdot-detour", ("--out", "thesis/../thesis"), ("thesis",), {}),
    ("user-folder-absolute", ("--out", "@ROOT@/thesis"), ("thesis",), {}),
    ("user-folder-hidden-file-only", ("--out", "keep"), ("keep",), {"files": {"keep/.gitkeep": ""}}),
    ("foreign-manifest", ("--out", "fm"), ("fm",), {"setup": _foreign_manifest}),
    ("ours-plus-a-user-file", ("--out", "prev"), ("prev",), {"setup": _ours_plus("my_notes.txt")}),
    (
        "symlink-to-user-folder",
        ("--out", "link_to_thesis"),
        ("link_to_thesis",),
        {"setup": _symlink("thesis", "link_to_thesis")},
    ),
    ("current-folder-dot", ("--out", "."), ("--out",), {}),
    ("current-folder-empty-dot", ("--out", "."), ("--out",), {"setup": _mkdirs("empty"), "cwd": "empty"}),
    ("current-folder-by-name", ("--out", "../work"), ("--out",), {"setup": _mkdirs("work"), "cwd": "work"}),
    ("parent-folder-dotdot", ("--out", ".."), ("--out",), {"setup": _mkdirs("work"), "cwd": "work"}),
    ("ancestor-absolute", ("--out", "@ROOT@"), ("--out",), {"setup": _mkdirs("work/deep"), "cwd": "work/deep"}),
    ("filesystem-root", ("--out", "/"), ("--out",), {}),
    ("filesystem-root-double-slash", ("--out", "//"), ("--out",), {}),
    ("home-folder", ("--out", "@ROOT@/home"), ("--out",), {"setup": _home(), "cwd": "work"}),
    ("home-folder-empty", ("--out", "@ROOT@/home"), ("--out",), {"setup": _home(with_file=False), "cwd": "work"}),
    ("home-folder-tilde", ("--out", "~"), ("--out",), {"setup": _home(), "cwd": "work"}),
    (
        "ancestor-of-home",
        ("--out", "@ROOT@/users"),
        ("--out",),
        {"setup": _home(with_file=False, sub="users/me"), "cwd": "work"},
    ),
    ("under-a-file", ("--out", "notes.txt/sub"), ("notes.txt",), {}),
    ("deep-under-a-file", ("--out", "notes.txt/a/b/c"), ("notes.txt",), {}),
    ("is-a-file", ("--out", "notes.txt"), ("notes.txt",), {}),
    ("empty-string", ("--out", ""), ("--out",), {}),
    ("nul-in-path", ("--out", "a\x00b"), ("--out",), {}),
    ("full-disk", ("--out", "results_full"), ("results_full",), {"setup": _full_disk}),
    (
        "locked-by-a-live-writer",
        ("--out", "rlocked"),
        ("rlocked",),
        {"setup": _lock("rlocked", live=True), "max_s": 10.0},
    ),
    ("name-too-long", ("--out", "x" * 300), ("--out",), {"may_simulate": True}),
]:
    case(f"out-run-{_id}", "run", S, *TINY, *_argv, needles=_needles, **_kw)
case(
    "out-run-default-out-is-a-file",
    "run",
    "s.yaml",
    "--no-figures",
    "--quiet",
    needles=("out",),
    files={"s.yaml": BASE, "out": "a file named out\n"},
)
case(
    "out-run-default-target-is-user-folder",
    "run",
    "s.yaml",
    "--no-figures",
    "--quiet",
    needles=("hostile_seed1",),
    files={"s.yaml": BASE, "out/hostile_seed1/thesis.txt": "precious\n"},
)
for _id, _argv, _needles, _kw in [
    ("user-folder", ("--out", "thesis"), ("thesis",), {}),
    ("current-folder", ("--out", "."), ("--out",), {}),
    ("filesystem-root", ("--out", "/"), ("--out",), {}),
    ("home-folder", ("--out", "@ROOT@/home"), ("--out",), {"setup": _home(), "cwd": "work"}),
    ("under-a-file", ("--out", "notes.txt/mc"), ("notes.txt",), {}),
    ("full-disk", ("--out", "mc_full"), ("mc_full",), {"setup": _full_disk}),
    ("default-out-is-a-file", (), ("out",), {"files": {"out": "a file named out\n"}}),
]:
    case(f"out-montecarlo-{_id}", "montecarlo", S, *MC_TINY, *_argv, needles=_needles, **_kw)
for _id, _argv, _needles, _kw in [
    ("user-folder", ("--out", "thesis"), ("thesis",), {}),
    ("current-folder", ("--out", "."), ("--out",), {}),
    ("filesystem-root", ("--out", "/"), ("--out",), {}),
    ("under-a-file", ("--out", "notes.txt/cmp"), ("notes.txt",), {}),
]:
    case(
        f"out-compare-{_id}",
        "compare",
        S,
        "--runs",
        "1",
        "--workers",
        "1",
        *TINY_SET,
        "--quiet",
        *_argv,
        needles=_needles,
        **_kw,
    )

# Successful writes: only the output folder changes.
case("out-ok-new-folder", "run", S, *TINY, "--out", "fresh", code=0, changes=("fresh",), expect=_has_manifest("fresh"))
case(
    "out-ok-nested-new-folder", "run", S, *TINY, "--out", "a/b/c", code=0, changes=("a",), expect=_has_manifest("a/b/c")
)
case(
    "out-ok-empty-folder",
    "run",
    S,
    *TINY,
    "--out",
    "emptyout",
    code=0,
    setup=_mkdirs("emptyout"),
    changes=("emptyout",),
    expect=_has_manifest("emptyout"),
)
case(
    "out-ok-replaces-our-previous-run",
    "run",
    S,
    *TINY,
    "--out",
    "prev",
    code=0,
    setup=_ours_plus(None),
    changes=("prev",),
    expect=_has_manifest("prev"),
)
case(
    "out-ok-stale-staging-removed",
    "run",
    S,
    *TINY,
    "--out",
    "rstale",
    code=0,
    setup=_stale_staging,
    changes=("rstale", ".rstale.writing-abcd1234", ".rstale.replaced-efgh5678", ".other.writing-zz99yy88"),
    expect=lambda ctx, c: _stale_gone(ctx, c) + _has_manifest("rstale")(ctx, c),
)
case(
    "out-ok-dead-writer-lock-taken-over",
    "run",
    S,
    *TINY,
    "--out",
    "rdead",
    code=0,
    setup=_lock("rdead", live=False),
    changes=("rdead", ".rdead.lock"),
    expect=_lock_gone("rdead"),
)
# A scenario name is one sanitized component of out/<name>_seed<N>: never a write outside out/.
for _id, _name in [
    ("dotdot-dotdot", "../../escaped"),
    ("dotdot", "../escaped"),
    ("slash", "a/b"),
    ("backslash", "a\\\\b"),
    ("only-dotdot", ".."),
    ("only-dot", "."),
    ("hidden", ".hidden"),
    ("absolute", "@ROOT@/abs_escaped"),
    ("nul", "a\\0b"),
    ("long-190", "n" * 190),
    ("long-5000", "n" * 5000),
    ("newline", "a\\nb"),
    ("tilde", "~"),
]:
    case(
        f"out-name-{_id}",
        "run",
        S,
        *TINY,
        "--set",
        f'name="{_name}"',
        code=(0, 2),
        setup=_mkdirs("work/deep"),
        cwd="work/deep",
        changes=("work/deep/out",),
        expect=_one_safe_folder("work/deep/out"),
    )
case(
    "out-name-dotdot-in-yaml-file",
    "run",
    "s.yaml",
    "--no-figures",
    "--quiet",
    code=(0, 2),
    files={"work/deep/s.yaml": _set_value(BASE, "name", 0, "../../escaped")},
    cwd="work/deep",
    changes=("work/deep/out",),
    expect=_one_safe_folder("work/deep/out"),
)
case(
    "out-name-dotdot-montecarlo",
    "montecarlo",
    S,
    *MC_TINY,
    "--set",
    "name=../../escaped",
    code=(0, 2),
    setup=_mkdirs("work/deep"),
    cwd="work/deep",
    changes=("work/deep/out",),
    expect=_one_safe_folder("work/deep/out"),
)

assert len(CASES) >= 150, len(CASES)


def _sparse(path: str, size: int) -> None:
    with open(path, "wb") as f:
        f.truncate(size)


# --------------------------------------------------------------------------------------------
# Shared result folders (one tiny run and one tiny campaign per module)
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def result_folders(tmp_path_factory):
    from drake_att.cli import main

    base = tmp_path_factory.mktemp("hostile_results")
    run, campaign = str(base / "run"), str(base / "campaign")
    code = main(["run", S, *TINY, "--out", run])
    assert code == 0, "the tiny run for the result-folder cases failed"
    code = main(["montecarlo", S, *MC_TINY, "--out", campaign])
    assert code == 0, "the tiny campaign for the resume cases failed"
    return {"run": run, "campaign": campaign}


def _user_files(root: str) -> None:
    """What a user keeps next to their runs (present in every case, checked by the snapshot)."""
    os.makedirs(os.path.join(root, "thesis"))
    with open(os.path.join(root, "thesis", "thesis.txt"), "w") as f:
        f.write("precious: three years of work\n")
    with open(os.path.join(root, "notes.txt"), "w") as f:
        f.write("notes\n")


def _write(path: str, content, root: str) -> None:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    if isinstance(content, str):
        content = content.replace(ROOT_TOKEN, root).encode("utf-8", "surrogateescape")
    with open(path, "wb") as f:
        f.write(content)


@pytest.mark.parametrize("case_id", list(CASES))
def test_hostile_input(case_id, tmp_path, capfd, monkeypatch, request):
    """Exit code, one ``drake-att`` line naming the input, no traceback, no long line, no
    write outside the test folder, and the files on disk unchanged (a success changes only
    its output folder)."""
    c = CASES[case_id]
    root = os.path.realpath(str(tmp_path))
    _user_files(root)
    for rel, content in (c.files or {}).items():
        _write(os.path.join(root, rel), content, root)
    ctx = Ctx(root, monkeypatch, request, [])
    try:
        if c.setup is not None:
            c.setup(ctx)
        monkeypatch.chdir(os.path.join(root, c.cwd))
        argv = [a.replace(ROOT_TOKEN, root) for a in c.argv]
        before = snapshot(root)
        expect_refusal = c.code == 2 and not c.may_simulate
        call = call_cli(argv, capfd, root, refuse_simulation=expect_refusal or None)
        after = snapshot(root)
        problems = message_problems(call, c.code, c.needles)
        changed = changed_paths(before, after)
        allowed = c.changes if call.code == 0 else ()
        stray = [p for p in changed if not any(_under(p, a) for a in allowed)]
        if stray:
            problems.append(f"files changed on disk that the call may not touch: {stray[:8]}")
        if c.ok_line and call.code == 0 and not re.search(r"\b(ok|valid)\b", call.out + call.err, re.I):
            problems.append("check exited 0 without a short OK line")
        if c.max_s is not None and call.seconds > c.max_s:
            problems.append(f"took {call.seconds:.1f} s; must be refused within {c.max_s} s")
        if c.expect is not None:
            problems += c.expect(ctx, call)
        assert not problems, f"{case_id}:\n  - " + "\n  - ".join(problems) + "\n" + call.describe()
    finally:
        for undo in ctx.cleanup:
            undo()


# --------------------------------------------------------------------------------------------
# Internal errors: exit 1, one line pointing to --debug; --debug shows the traceback
# --------------------------------------------------------------------------------------------
_INTERNAL = {
    "check": ("check", S),
    "run": ("run", S, *TINY, "--out", "r"),
    "score": ("score", "res"),
    "montecarlo": ("montecarlo", S, *MC_TINY, "--out", "mc"),
    "compare": ("compare", S, "--runs", "1", "--workers", "1", *TINY_SET, "--quiet", "--out", "cmp"),
    "list": ("list",),
}


def _inject_internal_error(monkeypatch) -> None:
    """An unexpected exception deep inside: resolving a scenario and computing metrics."""
    from drake_att.analysis import metrics
    from drake_att.scenarios import library

    def boom(*a, **k):
        raise RuntimeError("injected internal failure (not the user's fault)")

    monkeypatch.setattr(library, "scenario_path", boom)
    monkeypatch.setattr(library, "available_scenarios", boom)
    monkeypatch.setattr(metrics, "compute_metrics", boom)


@pytest.mark.parametrize("command", list(_INTERNAL))
def test_internal_error_exits_1_with_a_pointer_to_debug(command, tmp_path, capfd, monkeypatch, result_folders):
    root = os.path.realpath(str(tmp_path))
    shutil.copytree(result_folders["run"], os.path.join(root, "res"))
    monkeypatch.chdir(root)
    _inject_internal_error(monkeypatch)
    before = snapshot(root)
    c = call_cli(_INTERNAL[command], capfd, root, refuse_simulation=False)
    problems = message_problems(c, 1)
    lines = [line for line in c.err.splitlines() if line.strip()]
    if not lines or not lines[-1].startswith("drake-att") or "--debug" not in lines[-1]:
        problems.append("the last stderr line is not one 'drake-att ...' line mentioning --debug")
    stray = [p for p in changed_paths(before, snapshot(root)) if not _under(p, "res")]
    if stray:
        problems.append(f"files changed: {stray[:8]}")
    assert not problems, f"{command}:\n  - " + "\n  - ".join(problems) + "\n" + c.describe()


@pytest.mark.parametrize("command", ["check", "score"])
def test_debug_shows_the_traceback_of_an_internal_error(command, tmp_path, capfd, monkeypatch, result_folders):
    root = os.path.realpath(str(tmp_path))
    shutil.copytree(result_folders["run"], os.path.join(root, "res"))
    monkeypatch.chdir(root)
    _inject_internal_error(monkeypatch)
    c = call_cli([*_INTERNAL[command], "--debug"], capfd, root, refuse_simulation=False)
    shown = (c.raised is not None and "injected internal failure" in c.raised) or (
        c.code == 1 and "Traceback" in c.err and "injected internal failure" in c.err
    )
    assert shown, "--debug must re-raise or print the traceback of an internal error\n" + c.describe()


# --------------------------------------------------------------------------------------------
# Subprocess cases: a fresh interpreter (the current folder on sys.path; file-size limits)
# --------------------------------------------------------------------------------------------
ENV = dict(os.environ, MPLBACKEND="Agg")


def _cli(args, cwd, preexec_fn=None, timeout=120):
    return subprocess.run(
        [sys.executable, "-m", "drake_att.cli", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=ENV,
        preexec_fn=preexec_fn,
        timeout=timeout,
    )


def _completed_problems(r, code, needles=()) -> list[str]:
    return message_problems(Call(r.args, r.returncode, r.stdout, r.stderr, 0.0, None, [], []), code, needles)


def _plugin_result_folder(root: str, results: dict, module: str) -> str:
    folder = os.path.join(root, "downloaded")
    shutil.copytree(results["run"], folder)
    with open(os.path.join(folder, f"{module}.py"), "w") as f:
        f.write(f"open({os.path.join(root, 'PLUGIN_WAS_IMPORTED')!r}, 'w').write('imported')\n")
    _name_plugin_in_config(os.path.join(folder, "config.yaml"), module)
    return folder


@pytest.mark.parametrize("where", ["inside-the-folder", "from-its-parent"])
def test_score_of_a_downloaded_folder_never_imports_its_plugin(where, tmp_path, result_folders):
    """``python -m drake_att.cli score .`` inside a result folder that ships ``evil_plugin.py``
    and names it under ``plugins:``: refused (exit 2 naming it and ``--allow-plugins``), and the
    module never runs (its marker file is never created)."""
    root = os.path.realpath(str(tmp_path))
    folder = _plugin_result_folder(root, result_folders, "evil_plugin")
    before = snapshot(root)
    r = _cli(
        ["score", "."] if where == "inside-the-folder" else ["score", "downloaded"],
        cwd=folder if where == "inside-the-folder" else root,
    )
    problems = _completed_problems(r, 2, ("evil_plugin", "--allow-plugins"))
    if os.path.exists(os.path.join(root, "PLUGIN_WAS_IMPORTED")):
        problems.append("the plug-in module of a downloaded folder was imported (it ran code)")
    stray = changed_paths(before, snapshot(root))
    if stray:
        problems.append(f"files changed: {stray[:8]}")
    assert not problems, "\n  - ".join(problems) + "\n" + r.stderr[-2500:]


def test_score_allow_plugins_is_the_explicit_opt_in(tmp_path, result_folders):
    """With ``--allow-plugins`` the user chose to run the folder's plug-in: it is imported."""
    root = os.path.realpath(str(tmp_path))
    folder = _plugin_result_folder(root, result_folders, "evil_plugin")
    r = _cli(["score", ".", "--allow-plugins"], cwd=folder)
    assert "Traceback" not in r.stderr, r.stderr[-2500:]
    assert os.path.exists(os.path.join(root, "PLUGIN_WAS_IMPORTED")), (
        "--allow-plugins did not import the plug-in\n" + r.stderr[-2500:]
    )


def _file_size_limit(nbytes: int):
    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, nbytes))

    return limit


@pytest.mark.slow
def test_full_disk_while_writing_a_run_leaves_the_previous_results(tmp_path, result_folders):
    """A disk that fills while the results are written (``RLIMIT_FSIZE``: writes beyond 4 KiB
    fail with EFBIG): exit 2 naming the folder, no traceback, the previous results of ours at
    ``--out`` untouched and no staging folder or lock left behind."""
    root = os.path.realpath(str(tmp_path))
    _user_files(root)
    shutil.copytree(result_folders["run"], os.path.join(root, "results_fsize"))
    before = snapshot(root)
    r = _cli(["run", S, *TINY, "--out", "results_fsize"], cwd=root, preexec_fn=_file_size_limit(4096))
    problems = _completed_problems(r, 2, ("results_fsize",))
    stray = changed_paths(before, snapshot(root))
    if stray:
        problems.append(f"files changed or left behind: {stray[:8]}")
    assert not problems, "\n  - ".join(problems) + "\n" + r.stderr[-2500:]


@pytest.mark.parametrize("target", ["existing-metrics", "new-file"])
def test_full_disk_under_score_out_leaves_no_empty_or_partial_file(target, tmp_path, result_folders):
    """``score --out FILE`` on a full disk (``RLIMIT_FSIZE`` 256 bytes): exit 2 naming the file;
    an existing file keeps its content, a new one is not created (no 0-byte file)."""
    root = os.path.realpath(str(tmp_path))
    shutil.copytree(result_folders["run"], os.path.join(root, "res"))
    out = "res/metrics.json" if target == "existing-metrics" else "m.json"
    before = snapshot(root)
    r = _cli(["score", "res", "--out", out], cwd=root, preexec_fn=_file_size_limit(256))
    problems = _completed_problems(r, 2, (os.path.basename(out),))
    stray = changed_paths(before, snapshot(root))
    if stray:
        problems.append(f"files changed or left behind: {stray[:8]}")
    assert not problems, "\n  - ".join(problems) + "\n" + r.stderr[-2500:]


def _start_run_and_wait_for_the_simulation(root: str) -> subprocess.Popen:
    """``drake-att run cubesat_dual_star_tracker --out r`` in a fresh interpreter, returned once
    its progress line shows the simulation running (SIGINT/SIGTERM at their defaults, as a
    terminal user's process has)."""

    def defaults():
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)

    proc = subprocess.Popen(
        [sys.executable, "-m", "drake_att.cli", "run", "cubesat_dual_star_tracker", "--out", "r", "--no-figures"],
        cwd=root,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        preexec_fn=defaults,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line or "t =" in line or "%" in line:
            break
    return proc


@pytest.mark.slow
def test_sigterm_during_a_run_leaves_no_folder_lock_or_traceback(tmp_path):
    """SIGTERM (a scheduler's or systemd's stop) while simulating: a non-zero exit, no
    traceback, and nothing left on disk - no result folder, no staging folder, no lock."""
    root = os.path.realpath(str(tmp_path))
    _user_files(root)
    before = snapshot(root)
    proc = _start_run_and_wait_for_the_simulation(root)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    problems = []
    if proc.returncode == 0:
        problems.append("exit 0 after SIGTERM")
    if "Traceback" in err or "Traceback" in out:
        problems.append("a traceback reached the user")
    stray = changed_paths(before, snapshot(root))
    if stray:
        problems.append(f"left on disk: {stray[:8]}")
    assert not problems, "\n  - ".join(problems) + f"\nexit {proc.returncode}\n" + err[-2500:]


@pytest.mark.slow
def test_a_killed_writer_is_cleaned_up_by_the_next_run(tmp_path, capfd, monkeypatch):
    """SIGKILL (no handler can run) while simulating leaves at most a dead writer's lock and
    staging folder; the next run into the same folder takes them over and succeeds, and
    nothing of the killed run remains."""
    root = os.path.realpath(str(tmp_path))
    _user_files(root)
    before = snapshot(root)
    proc = _start_run_and_wait_for_the_simulation(root)
    proc.kill()
    proc.communicate(timeout=60)
    monkeypatch.chdir(root)
    c = call_cli(["run", S, *TINY, "--out", "r"], capfd, root)
    problems = message_problems(c, 0)
    left = [n for n in os.listdir(root) if n.startswith(".r.")]
    if left:
        problems.append(f"left by the killed writer: {left}")
    stray = [p for p in changed_paths(before, snapshot(root)) if not _under(p, "r")]
    if stray:
        problems.append(f"files changed outside r/: {stray[:8]}")
    assert not problems, "\n  - ".join(problems) + "\n" + c.describe()
