"""The `sweptvol watch` daemon as the add-on sees it, in plain Python (no bpy).

Whether a daemon runs on a folder (its heartbeat, `.sweptvol/daemon.json`: docs/exchange-protocol.md),
starting one (`sweptvol watch FOLDER`, its output in a log file in the folder) and stopping the
ones this process started (SIGTERM, at exit too). Tested by `blender_addon/tests/test_daemon.py`
against a fake daemon, without Blender.
"""

import atexit
import os
import subprocess
import time

if __package__:
    from . import exchange
else:  # imported on its own (the tests: the package __init__ needs bpy)
    import exchange

# A heartbeat older than this many of its intervals means no daemon (the contract's rule).
STALE_INTERVALS = 3.0
# The interval assumed when daemon.json does not give one (the daemon's own: src/watch/lock.rs).
DEFAULT_INTERVAL_S = 2.0
# Where a daemon this add-on starts writes its output (not a protocol name: the add-on's own).
LOG_NAME = ".sweptvol-addon-daemon.log"
# How long a started daemon is watched for an immediate exit (a bad folder, a second daemon).
SETTLE_S = 0.2
# How long a stopped daemon gets to finish its safe point before it is killed.
STOP_TIMEOUT_S = 10.0

_started = {}  # folder -> (Popen, log file): the daemons this process started


def heartbeat_path(folder):
    return os.path.join(folder, exchange.CONTROL_DIR, exchange.HEARTBEAT)


def alive(folder, now=None):
    """(alive, pid or None): a daemon runs on `folder` if `.sweptvol/daemon.json` says
    `running` and its heartbeat is less than three intervals old."""
    info = exchange.read_json(heartbeat_path(folder))
    if not info or info.get("state") != "running":
        return False, None
    now = time.time() if now is None else now
    try:
        age = now - float(info["heartbeat_at"])
        interval = float(info.get("heartbeat_interval_s", DEFAULT_INTERVAL_S))
    except (KeyError, TypeError, ValueError):
        return False, None
    return age < STALE_INTERVALS * interval, info.get("pid")


def command(binary, folder, backend=None):
    cmd = [binary, "watch", folder]
    if backend and backend != "auto":
        cmd += ["--backend", backend]
    return cmd


def status(folder):
    """(running, pid): a live heartbeat, or a daemon we started that has not exited yet."""
    live, pid = alive(folder)
    if live:
        return True, pid
    proc = _started.get(folder, (None, None))[0]
    if proc is not None and proc.poll() is None:
        return True, proc.pid
    return False, None


def started(folder):
    """The Popen of the daemon this process started on `folder` (running or not), or None."""
    return _started.get(folder, (None, None))[0]


def start(binary, folder):
    """Run `binary watch folder`, its output appended to `folder/LOG_NAME`.
    Returns (ok, message): message says why not, or ''. Raises OSError if the binary cannot be
    run or the log cannot be written."""
    stop(folder)  # one we started there that has exited: close its log
    log_path = os.path.join(folder, LOG_NAME)
    log = open(log_path, "ab")  # kept open while the daemon runs; closed by stop()
    try:
        proc = subprocess.Popen(command(binary, folder), stdin=subprocess.DEVNULL, stdout=log,
                                stderr=subprocess.STDOUT)
    except BaseException:
        log.close()
        raise
    _started[folder] = (proc, log)
    time.sleep(SETTLE_S)
    if proc.poll() is not None:
        return False, f"the sweptvol daemon exited at once (status {proc.returncode}); see {log_path}"
    return True, ""


def ensure(folder, binary, auto_start):
    """Start `sweptvol watch folder` if none runs and `auto_start` is on; `binary` is the
    program to start (None: not found). Returns (ok, message): message is a warning for the
    user, or ''. Raises OSError as `start` does."""
    running, _ = status(folder)
    if running:
        return True, ""
    if not auto_start:
        return False, (f"no sweptvol daemon seems to be running on {folder}: the job waits there "
                       f"until one starts (`sweptvol watch {folder}`, or turn on "
                       "'Start the daemon when needed')")
    if binary is None:
        return False, ("cannot start the daemon: the sweptvol binary was not found (set its path "
                       "in the add-on preferences); the job waits in the folder")
    return start(binary, folder)


def stop(folder=None, timeout=STOP_TIMEOUT_S):
    """Stop the daemons this process started (all, or the one on `folder`). SIGTERM: a daemon
    stops its running job at a safe point, leaves it queued for its next start, and exits."""
    for key in [k for k in _started if folder is None or k == folder]:
        proc, log = _started.pop(key)
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        log.close()


atexit.register(stop)
