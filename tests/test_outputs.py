"""Output folders (drake_att/outputs.py): which folders the library may replace, the lock, the
staging folders, atomic files. Each rule is checked on real folders in a temporary
directory, the expectations written from the rule (docs/guide/cli.md "What the library may touch"),
and every refusal leaves the files that were there byte for byte unchanged."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys

import pytest

from drake_att import outputs
from drake_att.outputs import OutputError


def snapshot(root) -> dict:
    """(relative path -> (size, sha256)) of every file under ``root``, and every folder."""
    out = {}
    for folder, _dirs, files in os.walk(root):
        rel = os.path.relpath(folder, root)
        out[rel + "/"] = None
        for name in files:
            path = os.path.join(folder, name)
            with open(path, "rb") as f:
                data = f.read()
            out[os.path.join(rel, name)] = (len(data), hashlib.sha256(data).hexdigest())
    return out


def make_run_folder(path, extra=()):
    """A run folder as `drake-att run` writes it: files plus a manifest listing them."""
    os.makedirs(path)
    files = {"metrics.json": b"{}", "log.npz": b"x" * 10}
    for name, data in files.items():
        with open(os.path.join(path, name), "wb") as f:
            f.write(data)
    entries = [{"file": n, "bytes": len(d), "sha256": hashlib.sha256(d).hexdigest()} for n, d in files.items()]
    with open(os.path.join(path, "manifest.json"), "w") as f:
        json.dump({"scenario": "s", "seed": 1, "files": entries}, f)
    for name in extra:
        with open(os.path.join(path, name), "w") as f:
            f.write("precious")


# --------------------------------------------------------------------------------------
# Which folders are ours
# --------------------------------------------------------------------------------------
def test_folder_kinds(tmp_path):
    (tmp_path / "empty").mkdir()
    make_run_folder(tmp_path / "run")
    make_run_folder(tmp_path / "run_plus", extra=["thesis.txt"])
    (tmp_path / "user").mkdir()
    (tmp_path / "user" / "thesis.txt").write_text("precious")
    (tmp_path / "fake").mkdir()
    (tmp_path / "fake" / "manifest.json").write_text('["not", "ours"]')
    (tmp_path / "camp").mkdir()
    (tmp_path / "camp" / "campaign.json").write_text('{"config_sha256": "ab", "record": "x"}')
    (tmp_path / "camp_cfg").mkdir()
    (tmp_path / "camp_cfg" / "config.yaml").write_text("# Resolved configuration of this Monte Carlo campaign\n")
    (tmp_path / "user_cfg").mkdir()
    (tmp_path / "user_cfg" / "config.yaml").write_text("# my notes\n")
    kinds = {
        name: outputs.folder_kind(str(tmp_path / name))
        for name in ("empty", "run", "run_plus", "user", "fake", "camp", "camp_cfg", "user_cfg")
    }
    assert kinds == {
        "empty": "empty",
        "run": "run",
        "run_plus": None,
        "user": None,
        "fake": None,
        "camp": "campaign",
        "camp_cfg": "campaign",
        "user_cfg": None,
    }


def test_a_comparison_folder_holds_only_campaigns_and_its_own_files(tmp_path):
    cmp_dir = tmp_path / "cmp"
    (cmp_dir / "scen_a").mkdir(parents=True)
    (cmp_dir / "scen_a" / "campaign.json").write_text('{"config_sha256": "ab", "record": "x"}')
    (cmp_dir / "comparison.json").write_text("{}")
    assert outputs.folder_kind(str(cmp_dir)) == "comparison"
    (cmp_dir / "notes.txt").write_text("mine")
    assert outputs.folder_kind(str(cmp_dir)) is None


# --------------------------------------------------------------------------------------
# check_target: refusals name the folder, leave everything unchanged
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "case, needle",
    [
        ("user_folder", "thesis.txt"),
        ("run_folder_with_a_user_file", "thesis.txt"),
        ("current_folder", "current folder"),
        ("parent_of_current", "current folder"),
        ("root", "root"),
        ("home", "home"),
        ("a_file", "existing file"),
        ("under_a_file", "is a file"),
        ("symlink_to_a_run", "symbolic link"),
        ("empty_name", "name a folder"),
        ("nul_in_name", "name a folder"),
    ],
)
def test_check_target_refuses_what_is_not_ours(tmp_path, monkeypatch, case, needle):
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    work = tmp_path / "work"
    (work / "inner").mkdir(parents=True)
    monkeypatch.chdir(work / "inner")
    (tmp_path / "user").mkdir()
    (tmp_path / "user" / "thesis.txt").write_text("precious")
    make_run_folder(tmp_path / "runx", extra=["thesis.txt"])
    make_run_folder(tmp_path / "run_ok")
    (tmp_path / "file").write_text("x")
    os.symlink(tmp_path / "run_ok", tmp_path / "link")
    target = {
        "user_folder": str(tmp_path / "user"),
        "run_folder_with_a_user_file": str(tmp_path / "runx"),
        "current_folder": ".",
        "parent_of_current": "..",
        "root": "/",
        "home": str(home),
        "a_file": str(tmp_path / "file"),
        "under_a_file": str(tmp_path / "file" / "sub"),
        "symlink_to_a_run": str(tmp_path / "link"),
        "empty_name": "",
        "nul_in_name": "a\x00b",
    }[case]
    before = snapshot(tmp_path)
    with pytest.raises(OutputError) as e:
        outputs.check_target(target)
    assert needle in str(e.value) and "\n" not in str(e.value)
    assert snapshot(tmp_path) == before


def test_check_target_accepts_new_empty_and_our_run_folders(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "empty").mkdir()
    make_run_folder(tmp_path / "run")
    for target in ("new/sub/folder", "empty", "run", str(tmp_path / "run")):
        assert outputs.check_target(target) == os.path.normpath(target)
    assert not (tmp_path / "new").exists()  # checking creates nothing


def test_check_target_refuses_a_file_system_without_room(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    free = outputs.shutil.disk_usage(str(tmp_path)).free
    with pytest.raises(OutputError, match="MiB free"):
        outputs.check_target("r", need_bytes=free + 1)
    outputs.check_target("r", need_bytes=0)


def test_campaign_kinds_are_separate_from_run_kinds(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    make_run_folder(tmp_path / "run")
    with pytest.raises(OutputError, match="run's result folder"):
        outputs.check_target("run", kinds=("empty", "campaign"))


# --------------------------------------------------------------------------------------
# Names made from a scenario
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name", ["../../escaped", "/etc/passwd", "a/b\\c", "..", ".", ".hidden", "x\x00y", "é" * 300, "", "   ", "a\nb"]
)
def test_safe_component_is_one_harmless_component(tmp_path, name):
    c = outputs.safe_component(name)
    assert c and len(c) <= outputs.MAX_COMPONENT
    assert os.sep not in c and "\\" not in c and "\x00" not in c and not c.startswith(".")
    joined = os.path.normpath(os.path.join(str(tmp_path), "out", c))
    assert os.path.dirname(joined) == os.path.join(str(tmp_path), "out")


# --------------------------------------------------------------------------------------
# The lock and the staging folders
# --------------------------------------------------------------------------------------
def test_a_second_writer_fails_fast_naming_the_first(tmp_path):
    target = str(tmp_path / "res")
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        with open(outputs.lock_path(target), "w") as f:
            f.write(f"{holder.pid} {outputs.socket.gethostname()}\n")
        with pytest.raises(OutputError, match=f"process {holder.pid}"):
            with outputs.writer_lock(target):
                pass
    finally:
        holder.kill()
        holder.wait()
    # The holder is dead now: its lock is taken over, and released at the end.
    with outputs.writer_lock(target) as path:
        assert open(path).read().split()[0] == str(os.getpid())
    assert not os.path.exists(outputs.lock_path(target))


def test_the_lock_removes_the_parents_it_made_when_nothing_was_written(tmp_path):
    target = tmp_path / "deep" / "er" / "res"
    with outputs.writer_lock(str(target)):
        assert (tmp_path / "deep" / "er").is_dir()
    assert os.listdir(tmp_path) == []
    with outputs.writer_lock(str(target)):
        target.mkdir()
    assert os.listdir(target.parent) == ["res"]


def test_the_lock_is_exclusive_within_one_process_too(tmp_path):
    target = str(tmp_path / "res")
    with outputs.writer_lock(target):
        with pytest.raises(OutputError, match="being written"):
            with outputs.writer_lock(target):
                pass
        assert os.path.exists(outputs.lock_path(target))


def test_stale_staging_is_removed_only_where_no_live_writer_holds_the_name(tmp_path):
    parent = tmp_path
    for name in (".res.writing-abc123", ".res.replaced-x_9", ".other.writing-zz", ".busy.writing-q1"):
        (parent / name).mkdir()
        (parent / name / "log.npz").write_text("partial")
    (parent / ".res.writing-not_ours!").mkdir()  # not our pattern: kept
    (parent / "user.writing-abc").mkdir()  # not hidden: kept
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (parent / ".busy.lock").write_text(f"{live.pid} {outputs.socket.gethostname()}\n")
        with outputs.writer_lock(str(parent / "res")):
            left = sorted(os.listdir(parent))
    finally:
        live.kill()
        live.wait()
    assert left == sorted([".busy.lock", ".busy.writing-q1", ".res.lock", ".res.writing-not_ours!", "user.writing-abc"])


def test_replace_folder_is_atomic_and_keeps_the_old_results_on_failure(tmp_path):
    target = str(tmp_path / "res")

    def write(names):
        def into(staging):
            for n in names:
                with open(os.path.join(staging, n), "w") as f:
                    f.write(n)
            return names

        return into

    outputs.replace_folder(target, write(["a.txt"]))
    with open(os.path.join(target, "manifest.json"), "w") as f:  # make it one of our run folders
        json.dump({"files": [{"file": "a.txt"}]}, f)
    before = snapshot(tmp_path)

    def failing(staging):
        with open(os.path.join(staging, "half.txt"), "w") as f:
            f.write("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        outputs.replace_folder(target, failing)
    assert snapshot(tmp_path) == before  # the old folder, and no staging left behind
    files = outputs.replace_folder(target, write(["b.txt"]))
    assert files == [os.path.join(target, "b.txt")]
    assert sorted(os.listdir(tmp_path)) == ["res"] and os.listdir(target) == ["b.txt"]


def test_replace_folder_refuses_a_folder_that_became_somebody_elses(tmp_path):
    target = tmp_path / "res"
    target.mkdir()
    (target / "thesis.txt").write_text("precious")
    with pytest.raises(OutputError, match="thesis.txt"):
        outputs.replace_folder(str(target), lambda staging: [])
    assert (target / "thesis.txt").read_text() == "precious"
    assert sorted(os.listdir(tmp_path)) == ["res"]


def test_write_file_atomic_leaves_the_old_file_when_the_write_fails(tmp_path):
    """A full disk (RLIMIT_FSIZE makes the write fail with EFBIG) leaves the old file whole,
    no 0-byte file and no temporary."""
    path = tmp_path / "metrics.json"
    path.write_text('{"old": true}')
    code = (
        "import resource, signal, sys\n"
        "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (100, 100))\n"
        "from drake_att.outputs import write_file_atomic\n"
        "try:\n"
        f"    write_file_atomic({str(path)!r}, b'x' * 10000)\n"
        "except OSError as e:\n"
        "    print('refused', e.errno)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.stdout.startswith("refused"), r.stderr
    assert path.read_text() == '{"old": true}' and os.listdir(tmp_path) == ["metrics.json"]
    outputs.write_file_atomic(str(path), b"new")
    assert path.read_bytes() == b"new" and os.listdir(tmp_path) == ["metrics.json"]


# --------------------------------------------------------------------------------------
# Details the mutation sample found untested
# --------------------------------------------------------------------------------------
def test_a_refusal_names_the_files_that_are_not_ours_first_and_counts_the_rest(tmp_path):
    folder = tmp_path / "camp"
    (folder / "runs").mkdir(parents=True)
    (folder / "runs" / "seed_1.npz").write_bytes(b"x")
    names = ["config.yaml", "summary.json", "report.html"]
    for n in names:
        (folder / n).write_text(n)
    entries = [{"file": n} for n in names] + [{"file": "runs/seed_1.npz"}]
    (folder / "manifest.json").write_text(json.dumps({"files": entries}))
    (folder / "zz_thesis.txt").write_text("precious")
    with pytest.raises(OutputError) as e:
        outputs.check_target(str(folder))
    # Sorted, the user's file would come last of 6 and be cut; not ours, it comes first.
    listing = str(e.value).split("did not write (")[1].split(")")[0]
    assert listing.startswith("zz_thesis.txt, ") and "(6 entries" in str(e.value)


def test_a_process_of_another_user_counts_as_alive(monkeypatch):
    def denied(pid, sig):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(outputs.os, "kill", denied)
    assert outputs._pid_alive(12345)


def test_a_folder_that_cannot_be_written_is_refused_before_any_work():
    """/proc refuses new entries even to root (chmod would not: we run as root)."""
    with pytest.raises(OutputError, match="cannot write in /proc"):
        outputs.check_target("/proc/drake_att_results")


def test_free_space_is_checked_at_its_boundary(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    need = 5 * 2**20
    usage = outputs.shutil.disk_usage(str(tmp_path))
    for free, ok in (
        (need + outputs.FREE_SPACE_MARGIN_BYTES, True),
        (need + outputs.FREE_SPACE_MARGIN_BYTES - 1, False),
    ):
        monkeypatch.setattr(outputs.shutil, "disk_usage", lambda p, f=free: usage._replace(free=f))
        if ok:
            outputs.check_target("r", need_bytes=need)
        else:
            with pytest.raises(OutputError, match="MiB free"):
                outputs.check_target("r", need_bytes=need)


def test_the_replacement_recheck_names_the_option(tmp_path):
    target = tmp_path / "res"
    target.mkdir()
    (target / "thesis.txt").write_text("precious")
    with pytest.raises(OutputError, match=r"^--out .*thesis\.txt"):
        outputs.replace_folder(str(target), lambda staging: [])


def test_write_file_atomic_stages_a_hidden_sibling(tmp_path, monkeypatch):
    """The temporary is beside the file (one file system: the rename is atomic) and hidden."""
    seen = []
    real = os.replace
    monkeypatch.setattr(outputs.os, "replace", lambda src, dst: (seen.append(src), real(src, dst)))
    outputs.write_file_atomic(str(tmp_path / "metrics.json"), b"{}")
    (src,) = seen
    assert os.path.dirname(src) == str(tmp_path) and os.path.basename(src).startswith(".metrics.json.tmp-")
