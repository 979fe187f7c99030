"""The add-on's protocol names are the daemon's: `sweptvol protocol` prints every name of the
folder protocol as JSON (src/watch/protocol.rs), and each constant of exchange.py that spells
one must equal it. A name the Rust side renames, or a job key it adds or drops, fails here
instead of in a user's watched folder.

The binary: SWEPTVOL_BIN, else target/release/sweptvol (conftest.py; SWEPTVOL_REQUIRE_BIN=1
makes a missing one a failure). Run: target/test-venv/bin/python -m pytest blender_addon/tests
"""

import json
import os
import subprocess
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "sweptvol_addon"))
import exchange as ex  # noqa: E402  (the module itself: the package __init__ needs bpy)

# JSON path (keys from the top) -> the add-on's value for it; lists compare in order unless the
# path is in AS_SETS.
ADDON = {
    ("partial_suffix",): ex.PARTIAL_SUFFIX,
    ("control_dir",): ex.CONTROL_DIR,
    ("heartbeat",): ex.HEARTBEAT,
    ("job_files", "generator_glb"): ex.GENERATOR_GLB,
    ("job_files", "generator_gltf"): ex.GENERATOR_GLTF,
    ("job_files", "trajectory"): ex.TRAJECTORY,
    ("job_files", "job_json"): ex.JOB_JSON,
    ("job_files", "cancel"): ex.CANCEL,
    ("outputs", "mesh"): ex.MESH,
    ("outputs", "start_mesh"): ex.START_MESH,
    ("outputs", "report"): ex.REPORT,
    ("outputs", "clearance_map"): ex.CLEARANCE_MAP,
    ("outputs", "status"): ex.STATUS,
    ("outputs", "depth_images"): list(ex.DEPTH_IMAGES),
    ("outputs", "also"): ex.ALSO_OUTPUTS,
    ("job_keys",): list(ex.JOB_KEYS),
    ("motions",): list(ex.MOTIONS),
    ("classify_methods",): list(ex.CLASSIFY_METHODS),
    ("radii",): list(ex.RADII),
    ("states",): list(ex.STATES),
    ("finished_states",): list(ex.FINISHED),
}
AS_SETS = {("job_keys",), ("motions",), ("classify_methods",), ("radii",), ("states",),
           ("finished_states",)}


def leaves(value, path=()):
    """Every (path, value) of a JSON object down to its non-object values."""
    if isinstance(value, dict):
        for key, inner in value.items():
            yield from leaves(inner, path + (key,))
    else:
        yield path, value


def lookup(doc, path):
    for key in path:
        if not isinstance(doc, dict) or key not in doc:
            raise KeyError(".".join(path))
        doc = doc[key]
    return doc


def compare(doc):
    """The differences between the binary's names and the add-on's, as readable lines (empty:
    they agree), and the JSON paths no add-on constant covers."""
    problems = []
    for path, ours in ADDON.items():
        name = ".".join(path)
        try:
            theirs = lookup(doc, path)
        except KeyError:
            problems.append(f"{name}: missing from `sweptvol protocol` (the add-on has {ours!r})")
            continue
        if path in AS_SETS:
            if not isinstance(theirs, list) or set(theirs) != set(ours) or len(theirs) != len(set(theirs)):
                extra = sorted(set(theirs) - set(ours)) if isinstance(theirs, list) else theirs
                gone = sorted(set(ours) - set(theirs)) if isinstance(theirs, list) else ours
                problems.append(f"{name}: the binary has {theirs!r}, the add-on {list(ours)!r} "
                                f"(only the binary's: {extra}; only the add-on's: {gone})")
        elif theirs != ours:
            problems.append(f"{name}: the binary says {theirs!r}, the add-on {ours!r}")
    uncovered = [p for p, _ in leaves(doc) if not any(p[: len(q)] == q for q in ADDON)]
    return problems, uncovered


def protocol_json(binary):
    proc = subprocess.run([binary, "protocol"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, (f"`{binary} protocol` exited {proc.returncode}: "
                                  f"{proc.stderr.strip() or proc.stdout.strip()}")
    try:
        doc = json.loads(proc.stdout)
    except ValueError as e:
        raise AssertionError(f"`{binary} protocol` did not print JSON ({e}): {proc.stdout[:500]!r}") from e
    assert isinstance(doc, dict), f"`{binary} protocol` printed {type(doc).__name__}, not an object"
    return doc


def test_the_addons_names_are_the_binarys(sweptvol_bin):
    problems, uncovered = compare(protocol_json(sweptvol_bin))
    assert not problems, "the add-on and sweptvol disagree on the protocol:\n  " + "\n  ".join(problems)
    if uncovered:  # a name the add-on has no constant for: not wrong, but worth knowing
        print("names with no add-on constant:", ", ".join(".".join(p) for p in uncovered))


# --- the comparison itself, against a fake binary (no sweptvol needed) ---------------------------

EXPECTED = {
    "partial_suffix": ".partial", "control_dir": ".sweptvol", "heartbeat": "daemon.json",
    "job_files": {"generator_glb": "generator.glb", "generator_gltf": "generator.gltf",
                  "trajectory": "trajectory.csv", "job_json": "job.json", "cancel": "cancel"},
    "outputs": {"mesh": "swept.glb", "start_mesh": "start.glb", "report": "report.json",
                "clearance_map": "clearance.glb",
                "status": "status.json",
                "depth_images": ["depth-xmin.exr", "depth-xmax.exr", "depth-ymin.exr",
                                 "depth-ymax.exr", "depth-zmin.exr", "depth-zmax.exr"],
                "also": {"stl": "swept.stl", "ply": "swept.ply", "obj": "swept.obj"}},
    "job_keys": ["resolution", "tolerance", "delta", "epsilon", "backend", "name", "motion",
                 "target_triangles", "keep_start_mesh", "also", "classify", "radii", "against",
                 "require_clearance", "clearance_scale", "relative_to", "rows", "package_dir"],
    "motions": ["screw", "discrete"],
    "classify_methods": ["auto", "flood", "axes"],
    "radii": ["exact", "paper"],
    "states": ["queued", "running", "done", "failed", "cancelled"],
    "finished_states": ["done", "failed", "cancelled"],
}


def fake_binary(tmp_path, doc, code=0):
    path = tmp_path / "sweptvol"
    text = json.dumps(doc) if not isinstance(doc, str) else doc
    path.write_text(f"#!/bin/sh\n[ \"$1\" = protocol ] || exit 2\ncat <<'EOF'\n{text}\nEOF\nexit {code}\n")
    path.chmod(0o755)
    return str(path)


def test_the_comparison_accepts_the_documented_json(tmp_path):
    problems, uncovered = compare(protocol_json(fake_binary(tmp_path, EXPECTED)))
    assert problems == [] and uncovered == []
    # job keys and states compare as sets; a new field the add-on does not know is no failure
    doc = json.loads(json.dumps(EXPECTED))
    doc["job_keys"].reverse()
    doc["drop_extensions"] = {"generator": "glb"}
    problems, uncovered = compare(doc)
    assert problems == [] and uncovered == [("drop_extensions", "generator")]


@pytest.mark.parametrize("path, value, words", [
    (("outputs", "mesh"), "result.glb", "outputs.mesh: the binary says 'result.glb'"),
    (("heartbeat",), "beat.json", "heartbeat: the binary says 'beat.json'"),
    (("outputs", "depth_images"), ["depth-xmin.exr"], "outputs.depth_images"),
    (("outputs", "also"), {"stl": "swept.stl"}, "outputs.also"),
    (("job_keys",), EXPECTED["job_keys"] + ["colour"], "only the binary's: ['colour']"),
    (("job_keys",), EXPECTED["job_keys"][1:], "only the add-on's: ['resolution']"),
    (("finished_states",), ["done", "failed"], "finished_states"),
])
def test_the_comparison_names_a_difference(path, value, words):
    doc = json.loads(json.dumps(EXPECTED))
    inner = doc
    for key in path[:-1]:
        inner = inner[key]
    inner[path[-1]] = value
    problems, _ = compare(doc)
    assert len(problems) == 1 and words in problems[0], problems


def test_the_comparison_names_a_missing_field():
    doc = json.loads(json.dumps(EXPECTED))
    del doc["job_files"]["cancel"]
    problems, _ = compare(doc)
    assert problems == ["job_files.cancel: missing from `sweptvol protocol` (the add-on has 'cancel')"]


def test_a_binary_without_the_subcommand_fails_worded(tmp_path):
    with pytest.raises(AssertionError, match="exited 2"):
        protocol_json(fake_binary(tmp_path, EXPECTED, code=2))
    with pytest.raises(AssertionError, match="did not print JSON"):
        protocol_json(fake_binary(tmp_path, "usage: sweptvol <command>"))
