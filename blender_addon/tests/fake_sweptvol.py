"""A stand-in for the sweptvol binary in test_daemon.py: `fake_sweptvol.py watch FOLDER [...]`.

Writes `FOLDER/.sweptvol/daemon.json` as `sweptvol watch` does (src/watch/lock.rs): state
`running`, its pid, `started_at`, `heartbeat_at` rewritten every `heartbeat_interval_s` (atomically:
a temporary file renamed over it); on SIGTERM it writes state `stopped` and exits 0. Its
arguments go to `FOLDER/fake-args.json`. The environment bends it:
  FAKE_INTERVAL_S   the heartbeat interval (default 2.0, the real daemon's);
  FAKE_EXIT         exit with this status at once, after a line on stderr (a refused start);
  FAKE_FIRST_BEAT_S wait this long before the first heartbeat (a slow start);
  FAKE_IGNORE_TERM  ignore SIGTERM (a daemon that does not stop: the caller must kill it).
"""

import json
import os
import signal
import sys
import time


def write_info(path, info):
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(info, f, indent=2)
    os.replace(tmp, path)


def main():
    args = sys.argv[1:]
    if len(args) < 2 or args[0] != "watch":
        print(f"fake sweptvol: usage: watch FOLDER (got {args})", file=sys.stderr)
        return 2
    if "FAKE_EXIT" in os.environ:
        print("fake sweptvol: refusing to start", file=sys.stderr, flush=True)
        return int(os.environ["FAKE_EXIT"])
    folder = args[1]
    control = os.path.join(folder, ".sweptvol")
    os.makedirs(control, exist_ok=True)
    with open(os.path.join(folder, "fake-args.json"), "w") as f:
        json.dump(args, f)
    interval = float(os.environ.get("FAKE_INTERVAL_S", "2.0"))
    stop = []
    if os.environ.get("FAKE_IGNORE_TERM"):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    else:
        signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    print("fake sweptvol: watching", folder, flush=True)
    time.sleep(float(os.environ.get("FAKE_FIRST_BEAT_S", "0")))
    path = os.path.join(control, "daemon.json")
    now = time.time()
    info = {"state": "running", "pid": os.getpid(), "sweptvol_version": "0.0.0-fake",
            "started_at": now, "heartbeat_at": now, "heartbeat_interval_s": interval}
    write_info(path, info)
    next_beat = time.monotonic() + interval
    while not stop:
        time.sleep(0.02)
        if time.monotonic() >= next_beat:
            info["heartbeat_at"] = time.time()
            write_info(path, info)
            next_beat += interval
    info["state"], info["heartbeat_at"] = "stopped", time.time()
    write_info(path, info)
    print("fake sweptvol: stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
