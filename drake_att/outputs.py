"""Output folders: which ones the library may write or replace, and how.

The rules a user can rely on (docs/guide/cli.md, "What the library may touch"):

* **Only folders of ours are replaced.** A run's folder is replaced only when it is empty or
  carries this library's ``manifest.json`` and nothing the manifest does not list; a
  campaign folder only when it holds this library's ``campaign.json`` (and then it is
  resumed, never replaced). Anything else is refused with the folder and what is in it.
* **Never** the current folder, a folder that contains it, the filesystem root, the home
  folder or a folder that contains it, and never through a symbolic link.
* **Names made from a scenario** (``out/<name>_seed<N>``) are one path component:
  :func:`safe_component` keeps letters, digits, ``.``, ``-`` and ``_`` and nothing that climbs
  out of ``out/``.
* **Checked before the work starts**: the parent can be created and written, and has free
  space for the estimated result (:func:`check_target`), so a long simulation never ends in
  a write error.
* **One writer per folder**: :func:`writer_lock` holds ``.<name>.lock`` beside the target
  (the writer's PID and host) for the whole run; a second writer of the same folder fails at
  once, naming the PID. A lock left by a killed process (dead PID on this host) is taken over.
* **Staging beside the target**: results are written into ``.<name>.writing-*`` and renamed
  into place; the folder being replaced is moved aside to ``.<name>.replaced-*`` and then
  deleted. Such folders left by a killed writer are removed by the next writer into the same
  parent (:func:`remove_stale_staging`), but only for names no live writer holds.

Every refusal is :class:`OutputError` (a ``ValueError``) with one line
``<option> <path>: <why>; <what to do>``.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import socket
import tempfile

from drake_att.interrupts import raise_if_interrupted
from drake_att.validation import UserInputError

MANIFEST = "manifest.json"
CAMPAIGN_FILE = "campaign.json"
LOCK_SUFFIX = ".lock"
STAGING_MARKS = (".writing-", ".replaced-")
# Kept free on the target's file system beyond the estimated result size.
FREE_SPACE_MARGIN_BYTES = 16 * 2**20
MAX_COMPONENT = 120
# A file name's limit on Linux file systems (ext4, xfs, tmpfs): the staging folder
# ``.<name>.writing-XXXXXXXX`` beside a result folder must fit in it too.
NAME_MAX = 255


class OutputError(UserInputError):
    """An output path the library refuses to write (the message names it and why)."""


def safe_component(name, fallback: str = "unnamed") -> str:
    """``name`` as one harmless path component: characters other than letters, digits,
    ``.``, ``-`` and ``_`` become ``_``; leading dots are dropped (no hidden names, no
    ``..``); at most :data:`MAX_COMPONENT` characters; ``fallback`` if nothing is left."""
    text = re.sub(r"[^A-Za-z0-9._-]", "_", str(name))
    text = text.lstrip(".")[:MAX_COMPONENT]
    return text if text.strip("_") else fallback


def _real(path: str) -> str:
    return os.path.realpath(os.path.abspath(os.path.expanduser(path)))


def _contains(ancestor: str, path: str) -> bool:
    """``path`` is ``ancestor`` or lies inside it (both real, absolute)."""
    return path == ancestor or path.startswith(ancestor.rstrip(os.sep) + os.sep)


def _protected_reason(real: str) -> str | None:
    """Why ``real`` (a resolved path) may never be written as a whole, or None."""
    if real == os.path.dirname(real):
        return "is the filesystem root"
    if _contains(real, _real(os.getcwd())):
        return "is the current folder or contains it"
    home = _real("~")
    if home and _contains(real, home):
        return "is the home folder or contains it"
    return None


def run_manifest_files(folder: str) -> list[str] | None:
    """The files a run folder's ``manifest.json`` lists (plus the manifest itself), or None
    when ``folder`` has no readable manifest of this library's shape."""
    path = os.path.join(folder, MANIFEST)
    try:
        with open(path, "rb") as f:
            data = json.loads(f.read(2**24).decode("utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not isinstance(data.get("files"), list):
        return None
    names = [e.get("file") for e in data["files"] if isinstance(e, dict)]
    if not all(isinstance(n, str) for n in names):
        return None
    return names + [MANIFEST]


def folder_kind(folder: str) -> str | None:
    """``"empty"``, ``"run"`` (a manifest of ours listing every file in it), ``"campaign"``
    (a ``campaign.json``, or a ``config.yaml`` with a campaign's header; a campaign is only
    ever resumed, and :func:`~drake_att.analysis.campaign.run_campaign` checks that its
    files are this library's), ``"comparison"`` (campaign folders and
    ``comparison.*`` files) or None (somebody else's folder)."""
    try:
        entries = os.listdir(folder)
    except OSError:
        return None
    if not entries:
        return "empty"
    if CAMPAIGN_FILE in entries or _has_campaign_config(folder):
        return "campaign"  # never replaced, only resumed: run_campaign judges its files
    listed = run_manifest_files(folder)
    if listed is not None and set(entries) <= {n.split("/")[0] for n in listed}:
        return "run"
    if all(_comparison_entry(folder, e) for e in entries):
        return "comparison"
    return None


def _comparison_entry(folder: str, name: str) -> bool:
    """``name`` belongs in a comparison folder: its own files, a campaign folder per scenario,
    or a staging folder or lock of ours."""
    path = os.path.join(folder, name)
    if name.startswith("comparison.") or name.endswith(LOCK_SUFFIX) or _staging_owner(name):
        return not os.path.islink(path)
    return os.path.isdir(path) and not os.path.islink(path) and folder_kind(path) in ("campaign", "empty")


CAMPAIGN_CONFIG_HEADER = b"# Resolved configuration of this Monte Carlo campaign"


def _has_campaign_config(folder: str) -> bool:
    try:
        with open(os.path.join(folder, "config.yaml"), "rb") as f:
            return f.read(len(CAMPAIGN_CONFIG_HEADER)) == CAMPAIGN_CONFIG_HEADER
    except OSError:
        return False


def _foreign(folder: str, limit: int = 3) -> str:
    """A few names in ``folder`` that are not ours (those a manifest does not list first)."""
    try:
        names = sorted(os.listdir(folder))
    except OSError as e:
        return f"unreadable ({e.strerror})"
    listed = {n.split("/")[0] for n in run_manifest_files(folder) or ()}
    names = sorted(names, key=lambda n: (n in listed, n))
    more = f", ... ({len(names)} entries)" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def _first_existing(path: str) -> str:
    while not os.path.lexists(path):
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    return path


def check_target(path: str, *, option: str = "--out", kinds=("empty", "run"), need_bytes: int = 0) -> str:
    """Check that ``path`` may be written as a result folder before any work starts; returns
    it normalized.

    Args:
        path: the folder to write (it may not exist yet).
        option: how the user named it, for messages (``--out``).
        kinds: what an existing folder may be (:func:`folder_kind`): ``("empty", "run")`` for
            a run's folder (replaced), ``("empty", "campaign")`` for a campaign (resumed).
        need_bytes: the estimated size of what will be written (checked against free space).

    Raises:
        OutputError: the path is protected, a file, a symbolic link, a folder of somebody
            else's, or its parent cannot be created or written or lacks the space.
    """
    if not isinstance(path, str) or not path.strip() or "\x00" in path:
        raise OutputError(f"{option}: got {path!r}; name a folder for the results")
    norm = os.path.normpath(os.path.expanduser(path))
    real = _real(norm)
    why = _protected_reason(real)
    if why:
        raise OutputError(f"{option} {path}: {why}; drake-att writes only into a new folder or one it wrote")
    if os.path.islink(norm):
        raise OutputError(f"{option} {path}: is a symbolic link; name the folder itself")
    if os.path.lexists(norm):
        if not os.path.isdir(norm):
            raise OutputError(f"{option} {path}: is an existing file, not a folder; name a folder for the results")
        kind = folder_kind(norm)
        if kind not in kinds:
            what = {"run": "a run's result folder", "campaign": "a Monte Carlo campaign folder"}.get(kind, "a folder")
            raise OutputError(
                f"{option} {path}: is {what} with files drake-att did not write ({_foreign(norm)}); "
                "drake-att replaces only empty folders and its own results - name a new folder"
            )
    longest = max(
        len(os.path.basename(real).encode("utf-8", "surrogateescape")) + len(".writing-XXXXXXXX") + 1,
        max(len(c.encode("utf-8", "surrogateescape")) for c in norm.split(os.sep) if c) if norm.strip(os.sep) else 0,
    )
    if longest > NAME_MAX:
        raise OutputError(
            f"{option} {path[:100]}...: a folder name is too long for the file system (at most "
            f"{NAME_MAX - len('.writing-XXXXXXXX') - 1} bytes for the result folder itself)"
        )
    parent = os.path.dirname(os.path.abspath(norm))
    existing = _first_existing(parent)
    if not os.path.isdir(existing):
        raise OutputError(f"{option} {path}: cannot be created: {existing} is a file, not a folder")
    _probe_writable(existing, option, path)
    free = shutil.disk_usage(existing).free
    if free < need_bytes + FREE_SPACE_MARGIN_BYTES:
        raise OutputError(
            f"{option} {path}: {free / 2**20:.0f} MiB free on its file system; the results need "
            f"~{(need_bytes + FREE_SPACE_MARGIN_BYTES) / 2**20:.0f} MiB - free some space or name "
            "another folder"
        )
    return norm


def _probe_writable(folder: str, option: str, path: str) -> None:
    import tempfile

    try:
        probe = tempfile.mkdtemp(prefix=".drake-att-probe-", dir=folder)
        os.rmdir(probe)
    except OSError as e:
        raise OutputError(
            f"{option} {path}: cannot write in {folder} ({e.strerror or e}); name a writable folder"
        ) from None


def lock_path(target: str) -> str:
    target = os.path.normpath(os.path.abspath(target))
    return os.path.join(os.path.dirname(target), f".{os.path.basename(target)}{LOCK_SUFFIX}")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # somebody else's live process
        return True
    return True


def _lock_holder(path: str) -> tuple[int, str] | None:
    """``(pid, host)`` written in a lock file, or None if unreadable."""
    try:
        with open(path) as f:
            pid, _, host = f.read(256).strip().partition(" ")
        return int(pid), host
    except (OSError, ValueError):
        return None


def _lock_is_live(path: str) -> bool:
    holder = _lock_holder(path)
    if holder is None:
        return False
    pid, host = holder
    return host != socket.gethostname() or _pid_alive(pid)


@contextlib.contextmanager
def writer_lock(target: str, option: str = "--out"):
    """Hold ``.<name>.lock`` beside ``target`` while writing it (see the module docstring).

    Raises:
        OutputError: another live process holds it (named by PID and host).
    """
    path = lock_path(target)
    created = _missing_folders(os.path.dirname(path))
    os.makedirs(os.path.dirname(path), exist_ok=True)
    me = f"{os.getpid()} {socket.gethostname()}\n"
    for _ in range(3):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            holder = _lock_holder(path)
            if holder is not None and _lock_is_live(path):
                raise OutputError(
                    f"{option} {target}: is being written by process {holder[0]} on {holder[1]} "
                    f"(lock {path}); wait for it to finish or name another folder"
                ) from None
            with contextlib.suppress(FileNotFoundError):  # a dead writer's (or an unreadable) lock
                os.remove(path)
            continue
        with os.fdopen(fd, "w") as f:
            f.write(me)
        break
    else:
        raise OutputError(f"{option} {target}: cannot take the lock {path}; another writer keeps taking it")
    try:
        remove_stale_staging(os.path.dirname(path))
        yield path
    finally:
        with contextlib.suppress(OSError):
            if _lock_holder(path) == (os.getpid(), socket.gethostname()):
                os.remove(path)
        for folder in created:  # parents made for the lock, left empty by a failed start
            with contextlib.suppress(OSError):
                os.rmdir(folder)


def _missing_folders(path: str) -> list[str]:
    """The folders ``os.makedirs(path)`` would create, deepest first."""
    missing = []
    path = os.path.abspath(path)
    while not os.path.lexists(path):
        missing.append(path)
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    return missing


def _staging_owner(name: str) -> str | None:
    """The target name of one of our staging folders ``.<target>.writing-XXXX`` /
    ``.<target>.replaced-XXXX``, or None for any other name."""
    if not name.startswith("."):
        return None
    for mark in STAGING_MARKS:
        head, found, tail = name[1:].rpartition(mark)
        if found and head and re.fullmatch(r"[A-Za-z0-9_]+", tail):
            return head
    return None


def remove_stale_staging(parent: str) -> list[str]:
    """Remove the staging folders in ``parent`` whose target no live writer holds (left by a
    killed or crashed writer); returns what was removed. A writer holding a target's lock
    owns its staging folders, so only names without a live lock are touched."""
    removed = []
    try:
        names = os.listdir(parent)
    except OSError:
        return removed
    for name in names:
        target = _staging_owner(name)
        full = os.path.join(parent, name)
        if target is None or not os.path.isdir(full) or os.path.islink(full):
            continue
        lock = os.path.join(parent, f".{target}{LOCK_SUFFIX}")
        mine = _lock_holder(lock) == (os.getpid(), socket.gethostname())
        if os.path.exists(lock) and _lock_is_live(lock) and not mine:
            continue
        if mine and name.startswith(f".{target}.writing-") and _in_use(full):
            continue
        shutil.rmtree(full, ignore_errors=True)
        removed.append(full)
    return removed


_IN_USE: set[str] = set()


def _in_use(path: str) -> bool:
    return os.path.abspath(path) in _IN_USE


def replace_folder(target: str, write, option: str = "--out") -> list[str]:
    """Write a folder atomically: ``write(staging) -> [file names]`` fills a fresh staging
    folder beside ``target``, which then replaces ``target`` in one rename (the previous
    folder, checked to be ours, is moved aside first and deleted after). ``target`` is
    complete or absent; an error or an interruption leaves the previous folder untouched.
    Returns the paths of the files written, under ``target``."""
    import tempfile

    target = os.path.normpath(target)
    parent = os.path.dirname(os.path.abspath(target))
    os.makedirs(parent, exist_ok=True)
    base = os.path.basename(target)
    staging = tempfile.mkdtemp(prefix=f".{base}.writing-", dir=parent)
    _IN_USE.add(os.path.abspath(staging))
    try:
        names = list(write(staging))
        raise_if_interrupted()  # a Ctrl-C swallowed while writing: the previous folder stays
        old = None
        if os.path.lexists(target):
            check_target(target, option=option)  # still ours (nothing changed it during the run)
            old = tempfile.mkdtemp(prefix=f".{base}.replaced-", dir=parent)
            os.rename(target, os.path.join(old, "previous"))
        os.rename(staging, target)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    finally:
        _IN_USE.discard(os.path.abspath(staging))
    return [os.path.join(target, n) for n in names]


def write_file_atomic(path: str, data: bytes) -> str:
    """``data`` into a temporary sibling of ``path``, flushed, then renamed onto it: ``path``
    is the old file or the new one, never empty or partial (a full disk leaves it as it was)."""
    import tempfile

    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.tmp-", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise
    return path


def script_folder_problem(out: str, our_files, marker_file: str, marker_key: str) -> str | None:
    """None if a diagram script may write its files into ``out``: absent, empty, or a folder it
    wrote (only names in ``our_files``, and ``marker_file`` a JSON object holding
    ``marker_key``); else the one-line reason. A user's files are never replaced."""
    if not os.path.lexists(out):
        return None
    if os.path.islink(out) or not os.path.isdir(out):
        return f"--out {out}: exists and is not a folder"
    names = sorted(os.listdir(out))
    if not names:
        return None
    foreign = [n for n in names if n not in our_files]
    mine = False
    try:
        with open(os.path.join(out, marker_file)) as f:
            data = json.load(f)
        mine = isinstance(data, dict) and marker_key in data
    except (OSError, ValueError):
        pass
    if foreign or not mine:
        what = f"holds {foreign[:3]}" if foreign else f"has no {marker_file} of this script"
        return f"--out {out}: {what}; it is not a folder this script wrote and is left untouched (name a new folder)"
    return None


def write_json_atomically(path: str, data) -> None:
    """``data`` as JSON at ``path``, whole or not at all (a temporary file in the same folder,
    then renamed over it)."""
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp_", suffix=".json")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=1)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
