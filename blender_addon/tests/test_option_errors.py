"""A bad option value reaches the panel named by the panel's own field.

The real daemon (`sweptvol watch --once`, see conftest.py) runs job folders whose job.json holds
a value it refuses. status.json must name the key (`error.column`) and spell it as the key in
`error.message`; `exchange.failure_text` must then word it by the panel field, with the fix in
the panel, and never show the job.json spelling or a command-line flag.

Run: target/test-venv/bin/python -m pytest blender_addon/tests
"""

import json
import os
import shutil
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(HERE, "..", "sweptvol_addon"))
import exchange as ex  # noqa: E402  (the module itself: the package __init__ needs bpy)


def run_job(sweptvol_bin, tmp_path, options):
    folder = tmp_path / "jobs"
    job = folder / "bad-job"
    job.mkdir(parents=True)
    shutil.copy(os.path.join(REPO, "examples", "bunny.glb"), job / ex.GENERATOR_GLB)
    shutil.copy(os.path.join(REPO, "examples", "bunny-vibration.csv"), job / ex.TRAJECTORY)
    (job / ex.JOB_JSON).write_text(json.dumps({"backend": "cpu", **options}))
    subprocess.run([sweptvol_bin, "watch", "--once", "--quiet", str(folder)], check=True,
                   timeout=120, capture_output=True)
    status = ex.read_status(str(job))
    assert status is not None and status["state"] == "failed", status
    return status


@pytest.mark.parametrize("options, key, label", [
    ({"resolution": 4}, "resolution", "Resolution"),
    ({"tolerance": -1.0}, "tolerance", "Tolerance"),
])
def test_a_refused_panel_value_is_named_by_its_field(sweptvol_bin, tmp_path, options, key, label):
    status = run_job(sweptvol_bin, tmp_path, options)
    error = status["error"]
    assert os.path.basename(error["file"]) == ex.JOB_JSON
    assert error["column"] == key
    assert f'"{key}"' in error["message"] and f"--{key}" not in status["message"], status
    text = ex.failure_text(status)
    assert text.startswith(label) and f"change {label} in the Swept Volume panel" in text, text
    assert f'"{key}"' not in text and "--" not in text, text
    assert ex.describe_status(status) == f"failed: {text}"


def test_a_key_the_panel_does_not_set_keeps_the_daemons_words(sweptvol_bin, tmp_path):
    # δ is not a panel field: the message stays the daemon's, naming the job.json key.
    status = run_job(sweptvol_bin, tmp_path, {"resolution": 64, "delta": 1e-9})
    assert status["error"]["column"] == "delta"
    assert ex.failure_text(status) == status["message"]
    assert '"delta"' in status["message"] and "job.json" in status["message"]
