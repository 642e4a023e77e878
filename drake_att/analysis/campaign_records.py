"""What a saved run of a campaign is, and how it is written, read and checked.

A campaign folder keeps each finished run in ``runs/``: ``seed_<seed>.npz`` (the run's
record, a dict of numpy arrays saved without pickles) or ``seed_<seed>.failed.txt`` (the
message of a run that went non-finite). Files are written atomically (a temporary sibling,
then ``os.replace``), so a file there is always complete; reading one is bounded
(:data:`MAX_RECORD_BYTES`) and refuses anything but plain arrays. Before a resume reuses a
saved record it is checked against the campaign's record layout and, for the default
record, against its documented structure (:func:`default_record_problem`), so a damaged or
foreign file is redone rather than reused. The folder logic that uses this is
:mod:`drake_att.analysis.campaign_folder` and :mod:`drake_att.analysis.campaign`; nothing
here imports them.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Callable

import numpy as np

from drake_att.analysis.dask_connection import _one_line
from drake_att.scenarios import config as cfg

RUNS_DIR = "runs"
# Reading a saved record is bounded: it expands to at most this many bytes (a 5000-s, 1-Hz
# run is ~0.5 MB per estimator).
MAX_RECORD_BYTES = 2**30


# ----------------------------------------------------------------------------------------
# The run files: where they are, written atomically, read without pickles
# ----------------------------------------------------------------------------------------
def _run_path(out: str, seed: int) -> str:
    return os.path.join(out, RUNS_DIR, f"seed_{seed}.npz")


def _failed_path(out: str, seed: int) -> str:
    return os.path.join(out, RUNS_DIR, f"seed_{seed}.failed.txt")


def _atomic_write(path: str, write: Callable) -> None:
    """``write(file)`` into a temporary sibling, flushed to disk, then renamed to ``path``:
    ``path`` is complete or absent, never half written."""
    tmp = os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise


def write_text_atomic(path: str, text: str) -> str:
    _atomic_write(path, lambda f: f.write(text.encode()))
    return path


def _saved_run_files(runs: str) -> list[str]:
    """The run files (``seed_<n>.npz``, ``seed_<n>.failed.txt``) in ``runs``."""
    try:
        names = os.listdir(runs)
    except OSError:
        return []
    return [n for n in names if re.fullmatch(r"seed_[0-9]+\.(npz|failed\.txt)", n)]


def _npz_arrays(record, seed: int) -> dict:
    if not isinstance(record, dict):
        raise TypeError(f"seed {seed}: a campaign record must be a dict of numpy arrays, got {type(record).__name__}")
    arrays = {}
    for key, value in record.items():
        a = np.asarray(value)
        if a.dtype == object:
            raise TypeError(
                f"seed {seed}: record entry {key!r} is not a plain numpy array (dtype object); "
                "records are saved without pickles"
            )
        arrays[key] = a
    return arrays


def save_record(out: str, seed: int, record) -> str:
    """``<out>/runs/seed_<seed>.npz``, atomically (``np.savez``, no pickles)."""
    path = _run_path(out, seed)
    arrays = _npz_arrays(record, seed)
    _atomic_write(path, lambda f: np.savez(f, **arrays))
    return path


def load_record(path: str) -> dict:
    """A saved record: ``np.load`` without pickles, every array read (a damaged file raises
    here). ValueError for a file that is not an ``.npz`` archive, an entry that is not a
    numpy array or an archive that expands beyond :data:`MAX_RECORD_BYTES`."""
    loaded = np.load(path, allow_pickle=False)
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise ValueError("a single .npy array, not an .npz archive of a record")
    with loaded as npz:
        size = sum(info.file_size for info in npz.zip.infolist())
        if size > MAX_RECORD_BYTES:
            raise ValueError(f"expands to {size} bytes, more than {MAX_RECORD_BYTES} (a record is a few MB)")
        record = {}
        for key in npz.files:
            value = npz[key]
            if not isinstance(value, np.ndarray):
                raise ValueError(f"entry {_one_line(repr(key), 80)} is not a numpy array")
            record[key] = value
    return record


# ----------------------------------------------------------------------------------------
# Is a saved record one of this campaign's? (checked before a resume reuses it)
# ----------------------------------------------------------------------------------------
# Two checks, so that a file edited by hand (or by another program) is redone rather than
# reused and crashing the summary later:
#
# * the *layout* every record of the campaign shares: its keys and, per key, the dtype kind,
#   the number of dimensions and every dimension but the first (the first is the number of
#   samples, which may differ from seed to seed). campaign.json keeps the layout of the
#   campaign's first fresh record ("record_layout"); a record function may declare keys
#   that some runs lack (``optional_key_suffixes``: the default record's bound arrays,
#   absent when a run has no bound). A record computed later with another layout replaces
#   it (records just computed are the reference, never a file);
# * for the default record, its documented structure (drake_att.analysis.ensemble),
#   derived from the scenario without a simulation: the keys of each estimator, shapes
#   consistent within the record (n estimate samples in t, dtheta, sigma, ...), the seed,
#   scenario and estimators it names, its JSON texts.
_KIND_NAMES = {"f": "float", "i": "int", "u": "unsigned int", "U": "str", "S": "bytes", "b": "bool", "c": "complex"}


def record_layout(record, optional_suffixes=()) -> dict:
    """``{key: [dtype kind, ndim, [every dimension but the first]]}`` of a record's arrays
    (keys ending in one of ``optional_suffixes`` left out)."""
    out = {}
    for key in sorted(record):
        if optional_suffixes and key.endswith(tuple(optional_suffixes)):
            continue
        a = np.asarray(record[key])
        out[key] = [a.dtype.kind, a.ndim, [int(d) for d in a.shape[1:]]]
    return out


def _valid_layout(value) -> dict | None:
    """A layout read from campaign.json, or None when it is absent or malformed (then the
    next fresh record sets it again)."""
    if not isinstance(value, dict) or not value:
        return None
    for key, entry in value.items():
        if not (
            isinstance(key, str)
            and isinstance(entry, list)
            and len(entry) == 3
            and isinstance(entry[0], str)
            and isinstance(entry[1], int)
            and not isinstance(entry[1], bool)
            and 0 <= entry[1] <= 32
            and isinstance(entry[2], list)
            and len(entry[2]) == max(entry[1] - 1, 0)
            and all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in entry[2])
        ):
            return None
    return value


def _layout_text(entry) -> str:
    kind, ndim, rest = entry
    name = _KIND_NAMES.get(kind, f"dtype kind {kind!r}")
    return f"{name} scalar" if ndim == 0 else f"{name} array of shape ({', '.join(['n'] + [str(d) for d in rest])})"


def _and_more(keys: list) -> str:
    """`` (and N more)`` after the first of ``keys`` when there are more."""
    return f" (and {len(keys) - 1} more)" if len(keys) > 1 else ""


def _layout_problem(record: dict, layout: dict, optional_suffixes=()) -> str | None:
    mine = record_layout(record, optional_suffixes)
    missing, extra = sorted(set(layout) - set(mine)), sorted(set(mine) - set(layout))
    if missing:
        return f"key {_one_line(repr(missing[0]), 80)} is missing{_and_more(missing)}"
    if extra:
        return f"unexpected key {_one_line(repr(extra[0]), 80)}{_and_more(extra)}"
    for key, entry in layout.items():
        if mine[key] != entry:
            return f"{key!r}: got a {_layout_text(mine[key])}; the campaign's records hold a {_layout_text(entry)}"
    return None


def _is_kind(a, kinds: str, ndim: int) -> bool:
    return isinstance(a, np.ndarray) and a.dtype.kind in kinds and a.ndim == ndim


# The default record's documented structure (drake_att.analysis.ensemble): dtype kinds of its
# scalars, and per estimator ``<name>__<suffix>``: (dtype kinds, ndim, columns or None).
_FLOAT, _INT, _STR = "f", "iu", "U"
_RECORD_SCALARS = {
    "schema": _INT,
    "scenario": _STR,
    "seed": _INT,
    "duration_s": _FLOAT,
    "score_from_s": _FLOAT,
    "convergence_threshold_deg": _FLOAT,
    "metrics_json": _STR,
}
_PER_ESTIMATOR = {
    "t": (_FLOAT, 1, None),
    "dtheta": (_FLOAT, 2, 3),
    "sigma": (_FLOAT, 2, 6),
    "nees": (_FLOAT, 1, None),
    "second_kind": (_STR, 0, None),
    "nees_dof": (_INT, 0, None),
    "window_n": (_INT, 0, None),
    "window_ms": (_FLOAT, 1, None),
    "window_ms_second": (_FLOAT, 1, None),
    "window_nees_sum": (_FLOAT, 0, None),
    "window_nees_n": (_INT, 0, None),
    "convergence_time_s": (_FLOAT, 0, None),
    "inputs": (_STR, 1, None),
    "nis_source": (_STR, 0, None),
    "bound_json": (_STR, 0, None),
}
_OPTIONAL_PER_ESTIMATOR = {
    "second_err": (_FLOAT, 2, 3),
    "bound_sigma": (_FLOAT, 2, 6),
    "bound_window_var": (_FLOAT, 1, None),
}


def _text(record: dict, key: str) -> str:
    return str(record[key])


def _is_json_object(record: dict, key: str) -> bool:
    try:
        return isinstance(json.loads(_text(record, key)), dict)
    except ValueError:
        return False


def _got(record: dict, key: str) -> str:
    """The layout of ``record[key]`` in words."""
    return _layout_text(record_layout({key: record[key]})[key])


def default_record_problem(record: dict, scenario: cfg.Scenario, seed: int) -> str | None:
    """Why ``record`` is not :func:`~drake_att.analysis.run_records.default_record` of run
    ``seed`` of ``scenario`` (None: it has the documented structure,
    :mod:`drake_att.analysis.ensemble`). Checks keys, dtype kinds and shapes, shapes
    consistent within the record, the seed, scenario, estimators and scoring it names, and
    that its JSON texts are JSON objects; derived from the scenario, no simulation needed."""
    names = [e.name for e in scenario.estimators]
    problem = _run_scalars_problem(record, scenario, seed) or _estimator_names_problem(record, names)
    if problem:
        return problem
    expected = set(_RECORD_SCALARS) | {"estimators"}
    for name in names:
        problem = _estimator_problem(record, f"{name}__", expected)
        if problem:
            return problem
    extra = sorted(set(record) - expected)
    if extra:
        return f"unexpected key {_one_line(repr(extra[0]), 80)}{_and_more(extra)}"
    return None


def _run_scalars_problem(record: dict, scenario: cfg.Scenario, seed: int) -> str | None:
    """The record's scalars: their kinds, the schema, and the seed, scenario and scoring they name."""
    from drake_att.analysis.ensemble import RECORD_SCHEMA

    for key, kinds in _RECORD_SCALARS.items():
        if key not in record:
            return f"key {key!r} is missing"
        if not _is_kind(record[key], kinds, 0):
            return f"{key!r}: got {_got(record, key)}; expected a scalar"
    if int(record["schema"]) != RECORD_SCHEMA:
        return f"record schema {int(record['schema'])}, this drake_att writes {RECORD_SCHEMA}"
    if int(record["seed"]) != seed:
        return f"it holds seed {int(record['seed'])}, not {seed}"
    if _text(record, "scenario") != scenario.name:
        return f"it holds scenario {_one_line(repr(_text(record, 'scenario')), 80)}, not {scenario.name!r}"
    for key, value in (
        ("duration_s", scenario.duration_s),
        ("score_from_s", scenario.scoring.score_from_s),
        ("convergence_threshold_deg", scenario.scoring.convergence_threshold_deg),
    ):
        if not abs(float(record[key]) - float(value)) <= 1e-9 * max(1.0, abs(float(value))):
            return f"{key} {float(record[key])!r}, the campaign's configuration has {float(value)!r}"
    if not _is_json_object(record, "metrics_json"):
        return "'metrics_json' is not a JSON object"
    return None


def _estimator_names_problem(record: dict, names: list) -> str | None:
    """The record's ``estimators``: the scenario's, in its order."""
    if "estimators" not in record or not _is_kind(record["estimators"], _STR, 1):
        return "'estimators' is missing or not an array of names"
    if [str(x) for x in record["estimators"]] != names:
        return f"it holds estimators {_one_line([str(x) for x in record['estimators']], 120)}, not {names}"
    return None


def _estimator_problem(record: dict, p: str, expected: set) -> str | None:
    """The arrays of the estimator whose keys start with ``p`` (their keys added to ``expected``)."""
    return (
        _estimator_kinds_problem(record, p, expected)
        or _estimator_shapes_problem(record, p)
        or _estimator_values_problem(record, p)
        or _nis_problem(record, p, expected)
    )


def _estimator_kinds_problem(record: dict, p: str, expected: set) -> str | None:
    """Each of the estimator's arrays is there (the optional ones may be absent), of its dtype
    kind, rank and number of columns."""
    for suffix, (kinds, ndim, cols) in list(_PER_ESTIMATOR.items()) + list(_OPTIONAL_PER_ESTIMATOR.items()):
        key = p + suffix
        if key not in record:
            if suffix in _OPTIONAL_PER_ESTIMATOR:
                continue
            return f"key {key!r} is missing"
        a = record[key]
        if not _is_kind(a, kinds, ndim) or (cols is not None and a.shape[1] != cols):
            want = "str" if kinds == _STR else "int" if kinds == _INT else "float"
            want += " scalar" if ndim == 0 else f" array of shape (n{', ' + str(cols) if cols else ''})"
            return f"{key!r}: got a {_got(record, key)}; expected a {want}"
        expected.add(key)
    return None


def _estimator_shapes_problem(record: dict, p: str) -> str | None:
    """The estimator's time series have as many samples as its times; its window arrays one
    entry per axis."""
    n = len(record[p + "t"])
    for suffix in ("dtheta", "sigma", "nees", "second_err", "bound_sigma"):
        if p + suffix in record and len(record[p + suffix]) != n:
            return f"'{p}{suffix}' has {len(record[p + suffix])} samples, '{p}t' {n}"
    for suffix, size in (("window_ms", 3), ("window_ms_second", 3), ("bound_window_var", 6)):
        if p + suffix in record and record[p + suffix].shape != (size,):
            return f"'{p}{suffix}': got shape {record[p + suffix].shape}; expected ({size},)"
    return None


def _estimator_values_problem(record: dict, p: str) -> str | None:
    """The estimator's times increase, and its kinds, degrees of freedom and JSON text are ones
    the summary reads."""
    t = record[p + "t"]
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) >= 0)):
        return f"'{p}t' is not a finite, increasing time series"
    if _text(record, p + "second_kind") not in ("gyro_bias", "body_rate"):
        return (
            f"'{p}second_kind' is {_one_line(repr(_text(record, p + 'second_kind')), 60)}, not gyro_bias or body_rate"
        )
    if int(record[p + "nees_dof"]) < 1:
        return f"'{p}nees_dof' is {int(record[p + 'nees_dof'])}; a NEES has at least 1 degree of freedom"
    source = _text(record, p + "nis_source")
    if source not in ("innovations", "status", "none"):
        return f"'{p}nis_source' is {_one_line(repr(source), 60)}, not innovations, status or none"
    if not _is_json_object(record, p + "bound_json"):
        return f"'{p}bound_json' is not a JSON object"
    return None


def _nis_problem(record: dict, p: str, expected: set) -> str | None:
    """The estimator's NIS samples: one (t, value, dof) triple per input, of equal lengths (none
    for the NIS source "none"); their keys added to ``expected``."""
    inputs = 0 if _text(record, p + "nis_source") == "none" else len(record[p + "inputs"])
    for i in range(inputs):
        keys = [f"{p}nis{i}__{k}" for k in ("t", "value", "dof")]
        for key, kinds in zip(keys, (_FLOAT, _FLOAT, _INT), strict=True):
            if key not in record:
                return f"key {key!r} is missing"
            if not _is_kind(record[key], kinds, 1):
                return f"{key!r}: got a {_got(record, key)}; expected a 1-d array"
            expected.add(key)
        if len({len(record[k]) for k in keys}) != 1:
            return f"'{p}nis{i}__t', '__value' and '__dof' differ in length"
    return None
