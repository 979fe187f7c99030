"""Tests of the add-on's daemon control (no Blender): the heartbeat rule, starting, stopping.

A fake daemon (fake_sweptvol.py, which writes `.sweptvol/daemon.json` as `sweptvol watch` does)
stands in for the binary, so starts that succeed, fail at once, start slowly or ignore SIGTERM
can all be tried; the last test starts and stops the real binary (see conftest.py).

Run: target/test-venv/bin/python -m pytest blender_addon/tests
"""

import json
import os
import stat
import subprocess
import sys
import time

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "sweptvol_addon"))
import daemon  # noqa: E402  (the module itself: the package __init__ needs bpy)
import exchange as ex  # noqa: E402

FAKE = os.path.join(HERE, "fake_sweptvol.py")


@pytest.fixture(autouse=True)
def _stop_started():
    yield
    daemon.stop(timeout=2)  # never leave a daemon behind, whatever a test did
    assert not daemon._started


@pytest.fixture
def fake_bin(tmp_path):
    """An executable 'sweptvol binary' that runs the fake daemon (exec: the same pid)."""
    path = tmp_path / "bin" / "sweptvol"
    path.parent.mkdir()
    path.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{FAKE}" "$@"\n')
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return str(path)


@pytest.fixture
def folder(tmp_path):
    path = tmp_path / "jobs"
    path.mkdir()
    return str(path)


def wait_until(predicate, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError(f"not within {timeout} s")


def beat(folder):
    return ex.read_json(daemon.heartbeat_path(folder)) or {}


def write_beat(folder, **info):
    os.makedirs(os.path.join(folder, ex.CONTROL_DIR), exist_ok=True)
    with open(daemon.heartbeat_path(folder), "w") as f:
        json.dump(info, f)


# --- the heartbeat rule and the command line ----------------------------------------------------

def test_heartbeat_path_is_the_protocols():
    assert daemon.heartbeat_path("/w") == os.path.join("/w", ".sweptvol", "daemon.json")


def test_daemon_liveness_from_heartbeat(folder):
    assert daemon.alive(folder) == (False, None)
    write_beat(folder, state="running", pid=4242, heartbeat_at=1000.0, heartbeat_interval_s=2.0)
    assert daemon.alive(folder, now=1005.0) == (True, 4242)
    assert daemon.alive(folder, now=1006.5) == (False, 4242)  # three intervals old: dead
    write_beat(folder, state="stopped", pid=4242, heartbeat_at=1000.0, heartbeat_interval_s=2.0)
    assert daemon.alive(folder, now=1000.5) == (False, None)


def test_heartbeat_without_interval_assumes_the_daemons():
    assert daemon.DEFAULT_INTERVAL_S == 2.0  # src/watch/lock.rs HEARTBEAT


def test_heartbeat_interval_defaults_and_garbage(folder):
    write_beat(folder, state="running", pid=7, heartbeat_at=1000.0)
    assert daemon.alive(folder, now=1005.9) == (True, 7)
    assert daemon.alive(folder, now=1006.0) == (False, 7)
    for bad in ({"state": "running", "pid": 7}, {"state": "running", "heartbeat_at": "soon"},
                {"state": "running", "heartbeat_at": 1.0, "heartbeat_interval_s": None}):
        write_beat(folder, **bad)
        assert daemon.alive(folder, now=1.0) == (False, None), bad
    with open(daemon.heartbeat_path(folder), "w") as f:
        f.write('{"state": "runn')  # a torn write (the daemon's are atomic, but be safe)
    assert daemon.alive(folder) == (False, None)


def test_command():
    assert daemon.command("/bin/sweptvol", "/w", "cpu") == [
        "/bin/sweptvol", "watch", "/w", "--backend", "cpu"]
    assert daemon.command("/bin/sweptvol", "/w", "auto") == ["/bin/sweptvol", "watch", "/w"]
    assert daemon.command("/bin/sweptvol", "/w") == ["/bin/sweptvol", "watch", "/w"]


# --- starting and stopping a (fake) daemon --------------------------------------------------------

def test_ensure_starts_a_daemon_and_stop_stops_it(fake_bin, folder, monkeypatch):
    monkeypatch.setenv("FAKE_INTERVAL_S", "0.1")
    assert daemon.status(folder) == (False, None)
    assert daemon.ensure(folder, fake_bin, auto_start=True) == (True, "")
    proc = daemon.started(folder)
    assert proc is not None and proc.poll() is None
    info = wait_until(lambda: beat(folder).get("state") == "running" and beat(folder))
    assert info["pid"] == proc.pid
    assert daemon.alive(folder) == (True, proc.pid)
    assert daemon.status(folder) == (True, proc.pid)
    with open(os.path.join(folder, "fake-args.json")) as f:
        assert json.load(f) == ["watch", folder]
    # the heartbeat moves on
    first = info["heartbeat_at"]
    wait_until(lambda: beat(folder).get("heartbeat_at", 0) > first)
    # a second ensure finds it and starts nothing
    assert daemon.ensure(folder, fake_bin, auto_start=True) == (True, "")
    assert daemon.started(folder) is proc
    _, log = daemon._started[folder]
    daemon.stop(folder)
    assert proc.returncode == 0 and log.closed
    assert beat(folder)["state"] == "stopped"
    assert daemon.alive(folder) == (False, None)
    assert daemon.status(folder) == (False, None)
    assert daemon.started(folder) is None
    with open(os.path.join(folder, daemon.LOG_NAME)) as f:
        text = f.read()
    assert "fake sweptvol: watching" in text and "fake sweptvol: stopped" in text


def test_a_live_heartbeat_means_no_start(fake_bin, folder):
    write_beat(folder, state="running", pid=4242, heartbeat_at=time.time(), heartbeat_interval_s=2.0)
    assert daemon.status(folder) == (True, 4242)
    assert daemon.ensure(folder, fake_bin, auto_start=True) == (True, "")
    assert daemon.started(folder) is None
    assert not os.path.exists(os.path.join(folder, daemon.LOG_NAME))


def test_a_stale_heartbeat_means_a_start(fake_bin, folder, monkeypatch):
    monkeypatch.setenv("FAKE_INTERVAL_S", "0.1")
    write_beat(folder, state="running", pid=4242, heartbeat_at=time.time() - 6.5, heartbeat_interval_s=2.0)
    assert daemon.status(folder) == (False, None)
    assert daemon.ensure(folder, fake_bin, auto_start=True) == (True, "")
    proc = daemon.started(folder)
    wait_until(lambda: beat(folder).get("pid") == proc.pid)
    assert daemon.alive(folder) == (True, proc.pid)


def test_a_started_daemon_counts_before_its_first_heartbeat(fake_bin, folder, monkeypatch):
    monkeypatch.setenv("FAKE_FIRST_BEAT_S", "30")
    assert daemon.ensure(folder, fake_bin, auto_start=True) == (True, "")
    proc = daemon.started(folder)
    assert daemon.alive(folder) == (False, None)
    assert daemon.status(folder) == (True, proc.pid)
    assert daemon.ensure(folder, fake_bin, auto_start=True) == (True, "")
    assert daemon.started(folder) is proc  # not a second one


def test_auto_start_off_starts_nothing_and_says_so(fake_bin, folder):
    ok, message = daemon.ensure(folder, fake_bin, auto_start=False)
    assert not ok and "no sweptvol daemon seems to be running on" in message and folder in message
    assert "Start the daemon when needed" in message
    assert daemon.started(folder) is None


def test_no_binary_found_says_so(folder):
    ok, message = daemon.ensure(folder, None, auto_start=True)
    assert not ok and "the sweptvol binary was not found" in message
    assert daemon.started(folder) is None


def test_a_binary_that_does_not_exist_raises_a_clear_oserror(tmp_path, folder):
    missing = str(tmp_path / "nowhere" / "sweptvol")
    with pytest.raises(FileNotFoundError) as err:
        daemon.ensure(folder, missing, auto_start=True)
    assert missing in str(err.value)
    assert daemon.started(folder) is None  # nothing recorded, the log not left open


def test_a_binary_that_is_not_executable_raises(tmp_path, folder):
    path = tmp_path / "sweptvol"
    path.write_text("not a program\n")
    with pytest.raises(PermissionError):
        daemon.ensure(folder, str(path), auto_start=True)
    assert daemon.started(folder) is None


def test_a_daemon_that_exits_at_once_is_reported_with_its_log(fake_bin, folder, monkeypatch):
    monkeypatch.setenv("FAKE_EXIT", "3")
    ok, message = daemon.ensure(folder, fake_bin, auto_start=True)
    log_path = os.path.join(folder, daemon.LOG_NAME)
    assert not ok and message == f"the sweptvol daemon exited at once (status 3); see {log_path}"
    assert daemon.status(folder) == (False, None)
    # the next try starts afresh (closing the dead one's log) and works
    monkeypatch.delenv("FAKE_EXIT")
    assert daemon.ensure(folder, fake_bin, auto_start=True) == (True, "")
    wait_until(lambda: beat(folder).get("state") == "running")
    with open(log_path) as f:
        assert "fake sweptvol: refusing to start" in f.read()


def test_a_daemon_that_ignores_sigterm_is_killed(fake_bin, folder, monkeypatch):
    monkeypatch.setenv("FAKE_IGNORE_TERM", "1")
    assert daemon.ensure(folder, fake_bin, auto_start=True) == (True, "")
    proc = daemon.started(folder)
    wait_until(lambda: beat(folder).get("state") == "running")
    t0 = time.monotonic()
    daemon.stop(folder, timeout=0.3)
    assert proc.returncode == -9 and time.monotonic() - t0 < 5
    assert beat(folder)["state"] == "running"  # killed: no clean exit, the heartbeat goes stale


def test_stop_one_folder_leaves_the_others(fake_bin, tmp_path):
    a, b = str(tmp_path / "a"), str(tmp_path / "b")
    os.mkdir(a)
    os.mkdir(b)
    assert daemon.ensure(a, fake_bin, auto_start=True) == (True, "")
    assert daemon.ensure(b, fake_bin, auto_start=True) == (True, "")
    pa, pb = daemon.started(a), daemon.started(b)
    daemon.stop(a)
    assert pa.returncode is not None and pb.poll() is None
    daemon.stop()
    assert pb.returncode == 0 and not daemon._started


def test_stop_at_exit_is_registered():
    # The add-on relies on it when Blender quits without disabling the add-on.
    code = ("import atexit, sys; sys.path.insert(0, sys.argv[1]); calls = []; "
            "atexit.register = lambda f, *a: calls.append(f); import daemon; "
            "assert calls == [daemon.stop], calls")
    subprocess.run([sys.executable, "-c", code, os.path.join(HERE, "..", "sweptvol_addon")], check=True)


# --- the real binary ----------------------------------------------------------------------------

def test_the_real_daemon_starts_beats_and_stops(sweptvol_bin, folder):
    assert daemon.ensure(folder, sweptvol_bin, auto_start=True) == (True, "")
    proc = daemon.started(folder)
    info = wait_until(lambda: beat(folder).get("state") == "running" and beat(folder))
    assert info["pid"] == proc.pid and info["heartbeat_interval_s"] == daemon.DEFAULT_INTERVAL_S
    assert daemon.alive(folder) == (True, proc.pid)
    daemon.stop(folder)
    assert proc.returncode == 0
    assert beat(folder)["state"] == "stopped"
    assert daemon.alive(folder) == (False, None)
