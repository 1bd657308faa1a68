"""`retarget --source-file ... --scheduler ADDRESS`: the clips on a real Dask scheduler with real worker processes
on 127.0.0.1 (tests/helpers/dask_cluster.py), each running the same clip worker as `--jobs`: the same files, the
same report rows and exit code as `--jobs 2`, and a Dask worker killed mid-clip loses no clip."""

import importlib
import json
import os
import signal
import threading
import time

import bpy
import numpy as np
import pytest

from tests.helpers.dask_cluster import HAS_DISTRIBUTED, WITHOUT_DISTRIBUTED, Cluster

from .test_cli import keyed_values, reopen, run
from .test_cli_clips import CUTS, good_clips, save_character

needs_distributed = pytest.mark.skipif(not HAS_DISTRIBUTED, reason=WITHOUT_DISTRIBUTED)

TIMES = ("seconds", "solve_seconds", "import_seconds")  # the only columns that differ from run to run


@pytest.fixture
def clips(tmp_path):
    return good_clips(tmp_path)


@pytest.fixture
def character(tmp_path, rig):
    return save_character(tmp_path, rig)


@pytest.fixture
def two_workers(tmp_path):
    running = Cluster(tmp_path, 2)
    yield running
    running.stop()


def batch(cli, capsys, character, clips, folder, *extra):
    """(exit code, report) of the clips retargeted into one .blend per clip in ``folder``."""
    folder.mkdir()
    code, _, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips,
                       "--output-dir", folder, "--quiet", "--report", folder / "report.json", *extra)
    report = json.loads((folder / "report.json").read_text())
    return code, report, err


def same_rows(report, local):
    """The rows of two runs, but for their times and output folder, are equal."""
    def plain(row):
        return {k: (os.path.basename(v) if k == "output" else v) for k, v in row.items() if k not in TIMES}
    assert [plain(row) for row in report["rows"]] == [plain(row) for row in local["rows"]]
    for key in ("clips", "frames", "missed_within_reach", "contacts_not_held"):
        assert report[key] == local[key], key


def same_actions(path, other):
    """The actions of two .blend files have the same keys, bit for bit."""
    reopen(path)
    mine = {a.name: keyed_values(a) for a in bpy.data.actions}
    reopen(other)
    theirs = {a.name: keyed_values(a) for a in bpy.data.actions}
    assert sorted(mine) == sorted(theirs) and mine
    for name, curves in mine.items():
        assert sorted(curves) == sorted(theirs[name])
        for key, values in curves.items():
            assert np.array_equal(values, theirs[name][key]), (name, key)


@needs_distributed
def test_clips_on_a_cluster_match_the_local_pool(cli, capsys, tmp_path, clips, character, two_workers):
    local_code, local, _ = batch(cli, capsys, character, clips, tmp_path / "local", "--jobs", 2)
    code, report, err = batch(cli, capsys, character, clips, tmp_path / "cluster", "--scheduler",
                              two_workers.address)
    assert code == local_code and report["jobs"] == 2, err
    assert [row["status"] for row in report["rows"]] == ["done"] * 3
    same_rows(report, local)
    for name in CUTS:
        same_actions(tmp_path / "cluster" / f"{name}.blend", tmp_path / "local" / f"{name}.blend")

    # Into one file (the workers' part files beside it), as --jobs merges them.
    merged, merged_local = tmp_path / "cluster.blend", tmp_path / "local.blend"
    bpy.ops.wm.read_homefile(use_empty=True)  # each run opens the character afresh, as a new process would
    assert run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips, "--scheduler",
               two_workers.address, "--output", merged, "--quiet")[0] == local_code
    bpy.ops.wm.read_homefile(use_empty=True)
    assert run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips, "--jobs", 2,
               "--output", merged_local, "--quiet")[0] == local_code
    same_actions(merged, merged_local)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("fba-parts-")) == []


def clip_workers(psutil, pid):
    """The clip worker processes process ``pid`` has started (none where it or they just ended)."""
    try:
        return [c for c in psutil.Process(pid).children() if "--clip-worker" in " ".join(c.cmdline())]
    except psutil.Error:
        return []


@needs_distributed
def test_a_dask_worker_killed_mid_clip_loses_no_clip(cli, capsys, tmp_path, clips, character, two_workers):
    import distributed
    import psutil

    watcher = distributed.Client(two_workers.address, set_as_default=False)
    watcher.wait_for_workers(2, timeout=60)
    pids = watcher.run(os.getpid)
    killed = {}

    def kill_one_mid_clip():
        """Kill the Dask worker of the first clip seen running as soon as its clip worker is up: a clip takes about
        a second on an idle machine, so waiting longer could see every clip end first."""
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            for address, keys in watcher.processing().items():
                workers = clip_workers(psutil, pids[address]) if keys else []
                if workers:
                    killed.update(address=address, keys=list(keys), clip_worker=workers[0])
                    os.kill(pids[address], signal.SIGKILL)
                    return
            time.sleep(0.01)

    killer = threading.Thread(target=kill_one_mid_clip)
    killer.start()
    try:
        code, report, err = batch(cli, capsys, character, clips, tmp_path / "cluster", "--scheduler",
                                  two_workers.address)
    finally:
        killer.join()
        watcher.close()
    assert killed, "no clip was seen running"
    assert [row["status"] for row in report["rows"]] == ["done"] * 3, err
    # Its clip worker ended with it (else it would have written its clip beside the retry).
    killed["clip_worker"].wait(timeout=5)
    assert not killed["clip_worker"].is_running()
    local_code, local, _ = batch(cli, capsys, character, clips, tmp_path / "local", "--jobs", 2)
    assert code == local_code
    same_rows(report, local)
    for name in CUTS:
        same_actions(tmp_path / "cluster" / f"{name}.blend", tmp_path / "local" / f"{name}.blend")


def test_cluster_options_that_cannot_work_are_one_line(cli, capsys, tmp_path, clips, character):
    for extra, words in ((("--scheduler", "tcp://127.0.0.1:9", "--jobs", "2"), "--jobs sets the local workers"),
                         (("--scheduler", "tcp://127.0.0.1:9"), "--scheduler tcp://127.0.0.1:9: cannot reach"
                          if HAS_DISTRIBUTED else "--scheduler needs the 'distributed' package")):
        code, out, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips,
                             "--output-dir", tmp_path / "out", *extra)
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "out").exists()


# Starts a clip worker (argv: its command as JSON, the fd of its stdin, its stdout's path), says its pid and waits.
PARENT = """
import json, subprocess, sys, time
with open(sys.argv[3], "w") as out:
    worker = subprocess.Popen(json.loads(sys.argv[1]), stdin=int(sys.argv[2]), stdout=out, pass_fds=(int(sys.argv[2]),))
print(worker.pid, flush=True)
time.sleep(600)
"""


def test_a_clip_worker_told_to_watch_its_parent_ends_with_it(tmp_path, character, extension_module_name):
    """A Dask worker's clip worker (job watch_parent) ends as soon as its parent is killed, although its stdin is
    still open (here held by the test): it writes nothing more."""
    import subprocess
    import sys

    cli_clips = importlib.import_module(f"{extension_module_name}.cli.clips")
    read, write = os.pipe()
    answers = tmp_path / "answers.jsonl"
    parent = subprocess.Popen([sys.executable, "-c", PARENT, json.dumps(cli_clips.worker_command()), str(read),
                               str(answers)], stdout=subprocess.PIPE, text=True, env=cli_clips.worker_env(),
                              pass_fds=(read,))
    os.close(read)
    worker = None
    try:
        worker = int(parent.stdout.readline())
        job = {"file": str(character), "target": "Hero", "import": {}, "watch_parent": True}
        os.write(write, (json.dumps(job) + "\n" + json.dumps({"clip": str(tmp_path / "none.bvh"), "name": "none",
                                                               "out": str(tmp_path / "none.blend")}) + "\n").encode())
        deadline = time.monotonic() + 120
        while '"row"' not in (answers.read_text() if answers.exists() else "") and time.monotonic() < deadline:
            time.sleep(0.1)  # the worker answered its task: it reads the next one, its stdin open
        assert '"failed"' in answers.read_text()
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + 10
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(worker)
    finally:
        os.close(write)
        if worker is not None and _alive(worker):
            os.kill(worker, signal.SIGKILL)


def _alive(pid):
    """Whether process ``pid`` runs (a zombie, ended but not yet reaped by init, does not)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_a_merged_cluster_batch_beside_a_folder_it_cannot_write_is_one_line(cli, capsys, tmp_path, clips, character,
                                                                             monkeypatch):
    # Root writes anywhere: the folder is reported unwritable as a user without the right would find it.
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda path, mode: path != str(tmp_path) and real_access(path, mode))
    code, _, err = run(cli, capsys, "retarget", character, "--target", "Hero", "--source-file", clips,
                       "--scheduler", "tcp://127.0.0.1:9")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"part files beside the input file, and folder {tmp_path} is not writable" in err
