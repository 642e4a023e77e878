"""The campaign folder: what is in it, created, taken back and read back on ``--resume``.

``config.yaml`` (the resolved scenario, under :data:`CONFIG_HEADER`), ``campaign.json``
(the campaign's identity: configuration hash, record function, record layout, executor),
``runs/`` (:mod:`drake_att.analysis.campaign_records`), and ``manifest.json`` last. Every
refusal is a one-line :class:`~drake_att.analysis.dask_connection.CampaignError` naming the
folder or file; reading the folder's small files is bounded.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable

from drake_att.analysis.campaign_records import (
    RUNS_DIR,
    _failed_path,
    _layout_problem,
    _run_path,
    _saved_run_files,
    default_record_problem,
    load_record,
    write_text_atomic,
)
from drake_att.analysis.dask_connection import CampaignError, _error_text, _one_line, _shown
from drake_att.analysis.run_records import default_record, record_name
from drake_att.scenarios import config as cfg

CONFIG_FILE = "config.yaml"
CAMPAIGN_FILE = "campaign.json"
SUMMARY_FILE = "summary.json"
MANIFEST_FILE = "manifest.json"
# Reading a campaign's small files (config.yaml, campaign.json, a failed run's message) is
# bounded too (saved records: MAX_RECORD_BYTES).
MAX_SIDE_FILE_BYTES = 2**20


def _record_check(record_fn: Callable, scenario: cfg.Scenario, layout: dict | None):
    """``check(record, seed) -> why not, or None`` for the records of a campaign."""
    optional = getattr(record_fn, "optional_key_suffixes", ())

    def check(record, seed):
        if record_fn is default_record:
            why = default_record_problem(record, scenario, seed)
            if why:
                return why
        return None if layout is None else _layout_problem(record, layout, optional)

    return check


def _small_file_text(path: str, limit: int = MAX_SIDE_FILE_BYTES) -> str:
    """The UTF-8 text of one of the campaign's own small files (config.yaml, campaign.json,
    a failed run's message): :func:`drake_att.scenarios.config.read_text_bounded`."""
    return cfg.read_text_bounded(path, limit)


def _read_small_file(path: str, what: str, limit: int = MAX_SIDE_FILE_BYTES) -> str:
    """:func:`_small_file_text`, or CampaignError ``<path>: <why>; <what>``."""
    try:
        return _small_file_text(path, limit)
    except ValueError as e:
        raise CampaignError(f"{_shown(path)}: {e}; {what}") from None


def _read_campaign_file(path: str) -> dict:
    """campaign.json as a dict; CampaignError naming the file when it is not the JSON
    object drake-att writes."""
    what = "it should be the JSON object drake-att writes there; name another --out"
    text = _read_small_file(path, what)
    try:
        info = json.loads(text)
    except ValueError as e:
        raise CampaignError(f"{_shown(path)}: not JSON ({_one_line(e, 120)}); {what}") from None
    if not isinstance(info, dict):
        raise CampaignError(f"{_shown(path)}: got a JSON {type(info).__name__}; {what}")
    return info


def _load_existing(out: str, seeds, check: Callable | None = None) -> tuple[dict, dict, list]:
    """Complete runs of ``seeds`` already in ``out/runs``: (records, failed, bad) with
    ``bad`` a list of ``(path, why)``: files that cannot be read, or whose record ``check``
    refuses (``check(record, seed) -> why or None``); their runs are redone."""
    records, failed, bad = {}, {}, []
    runs = os.path.join(out, RUNS_DIR)
    try:
        names = os.listdir(runs)
    except OSError as e:
        raise CampaignError(
            f"--resume {_shown(out)}: its {RUNS_DIR} folder cannot be read ({_one_line(e.strerror or e, 80)})"
        ) from None
    for name in names:
        if name.startswith(".") and ".tmp-" in name:  # a write that was interrupted
            try:
                os.remove(os.path.join(runs, name))
            except OSError:
                pass
    for seed in seeds:
        path, fpath = _run_path(out, seed), _failed_path(out, seed)
        for p in (path, fpath):
            if os.path.isdir(p) and not os.path.islink(p):  # a run's result could not be written there
                raise CampaignError(
                    f"--resume {_shown(out)}: {_shown(p)} is a folder, not a run file; move it "
                    "away, or name another --out"
                )
        if os.path.lexists(path):
            if not os.path.isfile(path):  # a link to nothing, a FIFO (reading it would block), a device
                bad.append((path, "unreadable (not a regular file)"))
                continue
            try:
                record = load_record(path)
            except Exception as e:  # noqa: BLE001 - any failure to read a file is a damaged file: its run is redone
                bad.append((path, f"unreadable ({_error_text(e)})"))
                continue
            why = None if check is None else check(record, seed)
            if why is None:
                records[seed] = record
            else:
                bad.append((path, f"not a record of this campaign ({why})"))
            continue
        if os.path.lexists(fpath):
            try:
                failed[seed] = _one_line(_small_file_text(fpath), 2000)
            except ValueError as e:
                bad.append((fpath, f"unreadable ({e})"))
    return records, failed, bad


def _campaign_identity(yaml_text: str, record: Callable) -> dict:
    return {"config_sha256": hashlib.sha256(yaml_text.encode()).hexdigest(), "record": record_name(record)}


def _first_difference(old: str, new: str) -> str:
    import difflib

    a, b = old.splitlines(), new.splitlines()
    for tag, i1, i2, j1, j2 in difflib.SequenceMatcher(None, a, b).get_opcodes():
        if tag != "equal":
            was = _one_line(a[i1].strip(), 100) if i1 < i2 else "(nothing)"
            now = _one_line(b[j1].strip(), 100) if j1 < j2 else "(nothing)"
            return f"line {i1 + 1}: the campaign has '{was}', this request '{now}'"
    return "(same text)"


CONFIG_HEADER = "# Resolved configuration of this Monte Carlo campaign (every run; seed per run).\n"


def _inspect_folder(out: str, yaml_text: str, record: Callable, resume: bool) -> tuple[str, dict | None]:
    """What ``out`` is for this campaign, read only (nothing is written before the cluster
    is connected): ``("new", None)`` (absent or empty, or a campaign of ours that saved no
    run: nothing to resume, it starts afresh), or ``("resume", campaign.json or None)``.
    CampaignError (one line, naming the folder or file) for anything else."""
    shown = _shown(out)
    if os.path.lexists(out) and not os.path.isdir(out):
        raise CampaignError(f"--out {shown}: is an existing file, not a folder; name a folder for the campaign")
    if not os.path.isdir(out):
        return "new", None
    config_path, cpath, runs = (os.path.join(out, n) for n in (CONFIG_FILE, CAMPAIGN_FILE, RUNS_DIR))
    has_config, has_campaign = os.path.lexists(config_path), os.path.lexists(cpath)
    try:
        entries = os.listdir(out)
    except OSError as e:
        raise CampaignError(
            f"--out {shown}: cannot be read ({_one_line(e.strerror or e, 80)}); name another folder"
        ) from None
    if not has_config and not has_campaign:
        if [n for n in entries if not n.startswith(".")]:
            raise CampaignError(
                f"--out {shown}: is a folder with other files in it (no {CONFIG_FILE} of a campaign); "
                "name a new or empty folder"
            )
        return "new", None
    info = _read_campaign_file(cpath) if has_campaign else None
    if os.path.lexists(runs) and not os.path.isdir(runs):
        raise CampaignError(f"--out {shown}: its {RUNS_DIR} is not a folder; name another --out")
    saved = _saved_run_files(runs)
    if not saved and info is not None and "config_sha256" in info and "record" in info:
        # A campaign of ours that saved no run (its start failed, or it was stopped before
        # the first run finished): nothing to keep or resume; it starts afresh, with or
        # without --resume, whatever configuration it had.
        try:
            ours = not has_config or _small_file_text(config_path).startswith(CONFIG_HEADER.split("(")[0])
        except ValueError:
            ours = False  # refused below, naming the file (--resume) or as a campaign already there
        if ours:
            return "new", info
    if not resume:
        n_failed = len([n for n in saved if n.endswith(".failed.txt")])
        runs_text = f"{len(saved) - n_failed} runs" + (f", {n_failed} failed" if n_failed else "")
        raise CampaignError(
            f"--out {shown}: holds a campaign already ({runs_text}); add --resume to continue it, or "
            "name another folder"
        )
    if not has_config:
        raise CampaignError(
            f"--resume {shown}: {CONFIG_FILE} is missing, so the configuration of its runs is unknown; "
            "name another --out"
        )
    old = _read_small_file(config_path, "the campaign's configuration (YAML written by drake-att); name another --out")
    old_yaml = old.split("\n", 1)[1] if old.startswith("#") else old
    if old_yaml != yaml_text:
        try:
            cfg._preparse(old_yaml, _shown(config_path))  # parse only: imports nothing the file names
        except Exception as e:  # noqa: BLE001 - any failure to parse it says the file is not a scenario
            raise CampaignError(
                f"--resume {shown}: {_shown(config_path)} is not a scenario ({_one_line(e, 160)}); name another --out"
            ) from None
        raise CampaignError(
            f"--resume {shown}: the campaign there ran another configuration "
            f"({_first_difference(old_yaml, yaml_text)}, in {_shown(config_path)}); give the same "
            "scenario, --set and --estimators, or another --out"
        )
    if info is not None and info.get("record") != record_name(record):
        raise CampaignError(
            f"--resume {shown}: the campaign there saved records of "
            f"{_one_line(repr(info.get('record')), 120)}, this request {record_name(record)}"
        )
    return "resume", info


def _create_folder(out: str, yaml_text: str) -> list[str]:
    """Create ``out/runs`` and write ``config.yaml``; returns what this created (files, then
    folders deepest first): what :func:`_remove_created` may take back."""
    runs = os.path.join(out, RUNS_DIR)
    missing, path = [], runs
    while not os.path.isdir(path):
        missing.append(path)
        parent = os.path.dirname(path)
        if not parent or parent == path:
            break
        path = parent
    config_path, cpath = os.path.join(out, CONFIG_FILE), os.path.join(out, CAMPAIGN_FILE)
    new_files = [p for p in (config_path, cpath) if not os.path.lexists(p)]
    os.makedirs(runs, exist_ok=True)
    write_text_atomic(config_path, CONFIG_HEADER + yaml_text)
    return new_files + missing


def _remove_created(out: str, created: list[str]) -> None:
    """Take back what :func:`_create_folder` created, when the campaign saved no run: a
    failed start leaves nothing behind. Files first, then folders only when empty; nothing
    that existed before is touched."""
    if _saved_run_files(os.path.join(out, RUNS_DIR)):
        return
    for path in created:
        try:
            if os.path.isdir(path) and not os.path.islink(path):
                os.rmdir(path)  # only an empty folder
            else:
                os.remove(path)
        except OSError:
            pass


def _write_campaign_file(out, scenario, seeds, record, executor: str, layout=None) -> str:
    import drake_att

    info = {
        "scenario": scenario.name,
        "first_seed": seeds[0],
        "runs": len(seeds),
        "seeds": [seeds[0], seeds[-1]],
        **_campaign_identity(cfg.dump_scenario(scenario), record),
        "drake_att": drake_att.__version__,
        "executor": executor,
    }
    if layout is not None:
        info["record_layout"] = layout
    return write_text_atomic(os.path.join(out, CAMPAIGN_FILE), json.dumps(info, indent=1) + "\n")


def write_campaign_manifest(out: str, files, scenario_name: str, seeds) -> str:
    """``manifest.json`` (as :func:`drake_att.analysis.report.write_manifest`, with paths
    relative to ``out`` so the runs in ``runs/`` are listed too), written last."""
    from drake_att.analysis.report import manifest_entries

    text = json.dumps(
        {
            "scenario": scenario_name,
            "seeds": [seeds[0], seeds[-1]],
            "runs": len(seeds),
            "files": manifest_entries(out, files),
        },
        indent=1,
    )
    return write_text_atomic(os.path.join(out, MANIFEST_FILE), text)


def check_campaign_manifest(out: str) -> list[str]:
    """Problems of a campaign folder against its manifest (empty: complete, unmodified)."""
    from drake_att.analysis.report import manifest_problems

    path = os.path.join(out, MANIFEST_FILE)
    if not os.path.isfile(path):
        return [f"{out}: no {MANIFEST_FILE} (the campaign did not finish)"]
    try:
        manifest = json.loads(_read_small_file(path, "it should be the manifest drake-att writes", 2**24))
    except (CampaignError, ValueError) as e:
        return [f"{_shown(path)}: unreadable ({_one_line(e, 200)})"]
    if not isinstance(manifest, dict) or not isinstance(manifest.get("files"), list):
        return [f"{_shown(path)}: not a manifest of drake-att (no list of files)"]
    return manifest_problems(out, manifest["files"])
