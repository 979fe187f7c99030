"""Tests of the add-on's exchange code (no Blender): job folders, CSV rows, status, transforms.

Run: target/test-venv/bin/python -m pytest blender_addon/tests
"""

import json
import math
import os
import struct
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "sweptvol_addon"))
import exchange as ex  # noqa: E402  (the module itself: the package __init__ needs bpy)


def close(a, b, tol=1e-12):
    return all(abs(a[i][j] - b[i][j]) <= tol for i in range(4) for j in range(4))


IDENT = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]


def translate(x, y, z):
    return [[1, 0, 0, x], [0, 1, 0, y], [0, 0, 1, z], [0, 0, 0, 1]]


def rot_z(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return [[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


def rot_x(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return [[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]]


def scale(x, y, z):
    return [[x, 0, 0, 0], [0, y, 0, 0], [0, 0, z, 0], [0, 0, 0, 1]]


def chain(*ms):
    out = ex.IDENTITY
    for m in ms:
        out = ex.matmul(out, m)
    return out


# --- transforms ---------------------------------------------------------------------------------

def test_axis_change_maps_blender_up_to_gltf_up():
    # Blender +Z (up) is glTF +Y; Blender +Y (forward) is glTF -Z.
    assert ex.transform_point(ex.C, (0, 0, 1)) == (0, 1, 0)
    assert ex.transform_point(ex.C, (0, 1, 0)) == (0, 0, -1)
    assert ex.gltf_point_to_blender(ex.transform_point(ex.C, (1, 2, 3))) == (1, 2, 3)


def test_blender_to_gltf_translation_by_hand():
    m = ex.blender_to_gltf(translate(1, 2, 3))
    assert close(m, translate(1, 3, -2))
    # a rotation about Blender Z is a rotation about glTF Y
    r = ex.blender_to_gltf(rot_z(90))
    assert ex.transform_point(r, (1, 0, 0)) == pytest.approx((0, 0, -1))


def test_affine_inverse():
    m = chain(translate(1, -2, 0.5), rot_z(30), rot_x(70), scale(2, 0.5, 3))
    assert close(ex.matmul(m, ex.affine_inverse(m)), ex.IDENTITY, 1e-12)
    with pytest.raises(ValueError):
        ex.affine_inverse(scale(1, 0, 1))


def test_row_maps_exported_geometry_to_its_place_at_the_frame():
    """The worked example: the exporter put the node at the pose of frame 0 (M_0), the object is
    at M_f at the frame; the row must move the file's point W·C·v to C·M_f·v."""
    m0 = chain(translate(0.5, 0, 0), rot_z(10), scale(1.5, 0.5, 0.8))
    mf = chain(translate(2, 1, 0.3), rot_z(60), rot_x(90), scale(1.5, 0.5, 0.8))
    w = ex.blender_to_gltf(m0)  # where the exporter placed the node (glTF space)
    row = ex.trajectory_row(mf, w)
    assert close(row, ex.matmul(ex.matmul(ex.C, ex.matmul(mf, ex.affine_inverse(m0))), ex.C_T), 1e-12)
    for v in [(0.5, 0.5, 0.5), (-0.5, 0.5, -0.5), (0.1, -0.2, 0.3)]:
        in_file = ex.transform_point(w, ex.transform_point(ex.C, v))
        placed = ex.transform_point(row, in_file)
        expected = ex.transform_point(ex.C, ex.transform_point(mf, v))
        assert placed == pytest.approx(expected, abs=1e-12)
        # and back in Blender space, that is where Blender shows the vertex
        assert ex.gltf_point_to_blender(placed) == pytest.approx(ex.transform_point(mf, v), abs=1e-12)


def test_row_numbers_by_hand():
    # Exported at the origin, at the frame translated by Blender (1, 2, 3): the row is the glTF
    # translation (1, 3, -2).
    row = ex.trajectory_row(translate(1, 2, 3), ex.IDENTITY)
    assert close(row, translate(1, 3, -2))
    # Exported translated by Blender (0, 0, 5) (glTF (0, 5, 0)), at the frame at the origin.
    row = ex.trajectory_row(ex.IDENTITY, ex.blender_to_gltf(translate(0, 0, 5)))
    assert close(row, translate(0, -5, 0))


def test_row_is_identity_when_exported_where_it_stands():
    m = chain(translate(3, 4, 5), rot_x(33), scale(2, 2, 2))
    assert close(ex.trajectory_row(m, ex.blender_to_gltf(m)), ex.IDENTITY, 1e-12)


def test_node_local_matrix_trs_and_matrix():
    # glTF quaternion (x, y, z, w) for 90 degrees about Y
    s = math.sqrt(0.5)
    m = ex.node_local_matrix({"translation": [1, 2, 3], "rotation": [0, s, 0, s], "scale": [2, 1, 1]})
    assert ex.transform_point(m, (1, 0, 0)) == pytest.approx((1, 2, 3 - 2))
    col_major = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 7, 8, 9, 1]
    assert close(ex.node_local_matrix({"matrix": col_major}), translate(7, 8, 9))


# --- GLB ----------------------------------------------------------------------------------------

def make_glb(path, doc, binary=b""):
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(js), ex.CHUNK_JSON) + js
    if binary:
        chunks += struct.pack("<II", len(binary), ex.CHUNK_BIN) + binary
    with open(path, "wb") as f:
        f.write(struct.pack("<III", ex.GLB_MAGIC, 2, 12 + len(chunks)) + chunks)


def tetra_glb(path, nodes, scene_nodes):
    pos = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    idx = [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3]
    binary = b"".join(struct.pack("<3f", *p) for p in pos) + struct.pack("<12H", *idx)
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": scene_nodes}], "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(binary) + (-len(binary) % 4)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48},
                        {"buffer": 0, "byteOffset": 48, "byteLength": 24}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
                      {"bufferView": 1, "componentType": 5123, "count": 12, "type": "SCALAR"}],
    }
    make_glb(path, doc, binary)


def test_mesh_node_worlds_compose_the_hierarchy(tmp_path):
    p = tmp_path / "a.glb"
    nodes = [{"name": "Parent", "translation": [10, 0, 0], "children": [1]},
             {"name": "Child", "mesh": 0, "scale": [2, 2, 2]},
             {"name": "Other", "mesh": 0}]
    tetra_glb(p, nodes, [0, 2])
    doc, _ = ex.read_glb(str(p))
    worlds = dict(ex.mesh_node_worlds(doc))
    assert set(worlds) == {"Child", "Other"}
    assert close(worlds["Child"], chain(translate(10, 0, 0), scale(2, 2, 2)))
    points, tris = ex.read_glb_mesh(str(p))
    assert len(points) == 8 and len(tris) == 8
    assert points[1] == pytest.approx((12, 0, 0))  # Child's (1,0,0) scaled and moved
    assert tris[4] == (4, 6, 5)


def test_a_rig_document_nests_the_meshes_under_their_joints(tmp_path):
    """The exported meshes under the rig's nodes: each node's world is the product of the
    locals given, the meshes are kept by name, the exporter's own nodes and skins are gone, and
    the bytes round-trip through read_glb."""
    p = tmp_path / "a.glb"
    tetra_glb(p, [{"name": "Upper", "mesh": 0, "translation": [5, 5, 5]},
                  {"name": "Fore", "mesh": 0, "skin": 0}], [0, 1])
    doc, binary = ex.read_glb(str(p))
    doc["skins"] = [{"joints": [0]}]
    rig = [("Rig", None, translate(0, 1, 0), None),
           ("Rig:Upper", 0, IDENT, None),
           ("Upper", 1, translate(0.5, 0, 0), "Upper"),
           ("Rig:Fore", 1, translate(1, 0, 0), None),
           ("Fore", 3, scale(2, 2, 2), "Fore")]
    out = ex.rig_document(doc, rig)
    q = tmp_path / "b.glb"
    q.write_bytes(ex.write_glb(out, binary))
    back, back_bin = ex.read_glb(str(q))
    assert back_bin[: len(binary)] == binary and "skins" not in back
    assert [n["name"] for n in back["nodes"]] == [r[0] for r in rig]
    assert back["scenes"][back["scene"]]["nodes"] == [0]
    assert "skin" not in back["nodes"][4]
    worlds = dict(ex.mesh_node_worlds(back))
    assert close(worlds["Upper"], translate(0.5, 1, 0))
    assert close(worlds["Fore"], chain(translate(1, 1, 0), scale(2, 2, 2)))
    with pytest.raises(ValueError, match="no mesh node named 'Hand'"):
        ex.rig_document(doc, [("Hand", None, IDENT, "Hand")])
    with pytest.raises(ValueError, match="does not come before"):
        ex.rig_document(doc, [("A", 1, IDENT, None), ("B", None, IDENT, None)])


def test_read_glb_refuses_other_files(tmp_path):
    p = tmp_path / "x.glb"
    p.write_bytes(b"not a glb file at all, no")
    with pytest.raises(ValueError):
        ex.read_glb(str(p))


# --- CSV ----------------------------------------------------------------------------------------

def test_csv_node_matrix_form():
    text = ex.trajectory_csv([(1.0, "Cube", ex.IDENTITY), (1.5, 'a, "b"', translate(1, 2, 3))])
    lines = [line for line in text.splitlines() if not line.startswith("#")]
    assert lines[0] == "frame,node," + ",".join(f"m{r}{c}" for r in range(4) for c in range(4))
    assert lines[1] == "1.0,Cube," + ",".join(["1.0", "0.0", "0.0", "0.0", "0.0", "1.0", "0.0", "0.0",
                                                "0.0", "0.0", "1.0", "0.0", "0.0", "0.0", "0.0", "1.0"])
    assert lines[2].startswith('1.5,"a, ""b""",1.0,0.0,0.0,1.0,')
    assert text.endswith("\n")


def test_csv_numbers_round_trip_and_refuse_non_finite():
    m = [row[:] for row in ex.IDENTITY]
    m[0][3] = 0.1 + 0.2
    text = ex.trajectory_csv([(0, "n", m)])
    assert repr(0.1 + 0.2) in text and float(repr(0.1 + 0.2)) == 0.1 + 0.2
    m[1][3] = float("nan")
    with pytest.raises(ValueError):
        ex.trajectory_csv([(0, "n", m)])
    with pytest.raises(ValueError):
        ex.csv_field("two\nlines")
    assert ex.csv_field(" padded") == '" padded"'


# --- job folders --------------------------------------------------------------------------------

def test_job_folder_is_written_partial_then_renamed(tmp_path):
    folder = str(tmp_path)
    name = ex.job_name("Part+Bar, the second", folder, now=0)
    assert not name.startswith(".") and not name.endswith(".partial")
    assert all(c.isalnum() or c in "-_" for c in name)
    partial = ex.begin_job(folder, name)
    assert partial.endswith(name + ".partial") and os.path.isdir(partial)
    with pytest.raises(FileNotFoundError):
        ex.commit_job(partial)  # no generator yet: nothing is committed
    open(os.path.join(partial, "generator.glb"), "wb").write(b"glb")
    ex.write_job_inputs(partial, "frame,node\n", {"resolution": 64, "backend": "cpu", "tolerance": None})
    assert json.load(open(os.path.join(partial, "job.json"))) == {"resolution": 64, "backend": "cpu"}
    job = ex.commit_job(partial)
    assert job == os.path.join(folder, name) and not os.path.exists(partial)
    assert sorted(os.listdir(job)) == ["generator.glb", "job.json", "trajectory.csv"]
    # the next name is fresh
    assert ex.job_name("Part+Bar, the second", folder, now=0) != name
    with pytest.raises(FileExistsError):
        ex.begin_job(folder, name)


def test_abandon_removes_the_partial_folder(tmp_path):
    partial = ex.begin_job(str(tmp_path), "j")
    open(os.path.join(partial, "generator.glb"), "wb").close()
    ex.abandon_job(partial)
    assert os.listdir(tmp_path) == []


def test_job_options_validation():
    assert ex.job_options(tolerance=0.05, backend="cpu", resolution=None) == {
        "tolerance": 0.05, "backend": "cpu"}
    assert ex.job_options(motion="discrete") == {"motion": "discrete"}
    for bad in ({"resolution": 64, "tolerance": 0.1}, {"colour": 1}, {"resolution": 0},
                {"tolerance": -1.0}, {"backend": "tpu"}, {"motion": "linear"}):
        with pytest.raises(ValueError):
            ex.job_options(**bad)
    with pytest.raises(ValueError):
        ex.begin_job("/tmp", "x.partial")
    with pytest.raises(ValueError):
        ex.begin_job("/tmp", ".hidden")


def test_cancel_file(tmp_path):
    ex.request_cancel(str(tmp_path))
    assert (tmp_path / "cancel").is_file()


# --- status, report (the daemon's heartbeat: test_daemon.py) -------------------------------------

def test_status_reading(tmp_path):
    job = str(tmp_path)
    assert ex.read_status(job) is None
    assert ex.describe_status(None) == "waiting for the daemon"
    (tmp_path / "status.json").write_text('{"state": "running", "stage": "sweep", "progress": 0.42}')
    assert ex.describe_status(ex.read_status(job)) == "running: sweep 42%"
    (tmp_path / "status.json").write_text('{"state": "failed", "message": "trajectory.csv: line 3"}')
    assert ex.describe_status(ex.read_status(job)) == "failed: trajectory.csv: line 3"
    (tmp_path / "status.json").write_text('{"state": "runn')  # never happens (atomic), but harmless
    assert ex.read_status(job) is None
    (tmp_path / "status.json").write_text("[1, 2]")
    assert ex.read_status(job) is None


def test_result_summary_from_report():
    report = {"sweptvol_version": "0.1.0", "resolution": [64, 40, 30],
              "mesh": {"hausdorff_bound": 0.08, "clearance": 0.01, "triangles_final": 500,
                       "vertices": 252, "volume": 1.5},
              "counts": {"poses": 34, "posed_triangles": 1000, "triangles": 30},
              "parameters": {"voxel_size": 0.02}}
    s = ex.result_summary(report)
    assert s["sweptvol_hausdorff_bound"] == 0.08 and s["sweptvol_poses"] == 34
    assert s["sweptvol_triangles"] == 500 and s["sweptvol_resolution"] == [64, 40, 30]
    assert ex.result_summary(None) == {}
    report["motion"] = {"model": "screw", "mu": 0.005, "poses_rendered": 40}
    sampling = {"worst_deviation": 0.002, "threshold": 0.01, "finest_step": 1 / 64,
                "rows_added": 3, "probes": 90, "unresolved": 0}
    s = ex.result_summary(report, sampling)
    assert s["sweptvol_motion"] == "screw" and s["sweptvol_sampling_deviation"] == 0.002
    assert s["sweptvol_sampling_threshold"] == 0.01 and s["sweptvol_sampling_unresolved"] == 0
    assert "sweptvol_sampling_deviation" not in ex.result_summary(report)


def test_sampling_record_is_written_beside_the_inputs_and_read_back(tmp_path):
    partial = ex.begin_job(str(tmp_path), "job")
    record = {"worst_deviation": 0.001, "threshold": 0.01, "objects": []}
    ex.write_job_inputs(partial, "frame,m00\n", {"resolution": 64}, record)
    assert json.load(open(os.path.join(partial, ex.SAMPLING))) == record
    assert ex.read_sampling(partial) == record
    other = ex.begin_job(str(tmp_path), "other")
    ex.write_job_inputs(other, "frame,m00\n", {"resolution": 64})
    assert not os.path.exists(os.path.join(other, ex.SAMPLING)) and ex.read_sampling(other) is None


# --- packaging ----------------------------------------------------------------------------------

def test_manifest_and_bl_info_agree():
    """Blender 4.2+ reads blender_manifest.toml, 3.x reads bl_info: same version, both present."""
    import ast
    import tomllib

    root = os.path.join(os.path.dirname(__file__), "..", "sweptvol_addon")
    with open(os.path.join(root, "blender_manifest.toml"), "rb") as f:
        manifest = tomllib.load(f)
    for key in ("schema_version", "id", "version", "name", "tagline", "maintainer", "type",
                "blender_version_min", "license"):
        assert key in manifest, key
    assert manifest["type"] == "add-on" and manifest["id"] == "sweptvol_addon"
    # Blender's `extension validate` (run on the real validators by run-e2e-all.sh) refuses a
    # tagline over 64 characters or ending in punctuation.
    assert len(manifest["tagline"]) <= 64 and manifest["tagline"][-1:].isalnum()
    tree = ast.parse(open(os.path.join(root, "__init__.py")).read())
    bl_info = next(ast.literal_eval(n.value) for n in tree.body
                   if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") == "bl_info")
    assert ".".join(map(str, bl_info["version"])) == manifest["version"]
    assert bl_info["blender"] <= (3, 4, 0)


def test_clearance_maps_read_back_as_the_binary_writes_them(tmp_path, sweptvol_bin):
    """A real run with the bundled housing: the add-on reads every obstacle of the map with its
    per-vertex lower ends, colours and closest points, and words each verdict for the panel."""
    import subprocess

    repo = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
    out = tmp_path / "out"
    run = subprocess.run(
        [sweptvol_bin, "run", "--generator", os.path.join(repo, "examples", "bunny.glb"),
         "--trajectory", os.path.join(repo, "examples", "bunny-vibration.csv"),
         "--out", str(out), "--resolution", "48", "--backend", "cpu", "--quiet",
         "--motion", "discrete", "--against", os.path.join(repo, "examples", "bunny-housing.glb")],
        capture_output=True, text=True, check=False)
    assert run.returncode == 0, run.stderr
    report = json.loads((out / "bunny-vibration.report.json").read_text())
    obstacles = ex.read_clearance_map(str(out / "bunny-vibration.bunny-housing.clearance.glb"))
    names = [o["name"] for o in obstacles]
    assert names == ["floor", "wall-west", "wall-east", "wall-north", "wall-south"]
    for o, r in zip(obstacles, report["clearance"]["obstacles"], strict=True):
        assert len(o["values"]) == len(o["points"]) == len(o["colours"]) > 0
        assert min(o["values"]) >= r["lower"] - 1e-6  # no vertex below the obstacle's lower end
        assert o["closest"] is not None and o["extras"]["sweptvol_verdict"] == r["verdict"]
    lines = ex.clearance_lines(report)
    assert [e["name"] for e in lines] == names  # no contact: the report's order
    first = report["clearance"]["obstacles"][0]
    assert lines[0]["line"] == (f"floor: {ex.VERDICT_WORDS[first['verdict']]}, clearance "
                                f"{first['lower']:.4g} to {first['upper']:.4g}")


def test_clearance_lines_put_contacts_first_and_name_the_witness():
    report = {"clearance": {"obstacles": [
        {"name": "wall", "verdict": "clear", "lower": 0.5, "upper": 0.8, "map": "m"},
        {"name": "pin", "verdict": "contact", "lower": 0.0, "upper": 0.0, "map": "m",
         "witness": {"part": "Arm", "row": 3, "line": 5, "how": "triangles cross"}},
        {"name": "lid", "verdict": "possible-contact", "lower": 0.0, "upper": None, "map": "m"},
    ]}}
    lines = ex.clearance_lines(report)
    assert [e["name"] for e in lines] == ["pin", "wall", "lid"]
    assert lines[0]["line"] == "pin: CONTACT (Arm triangles cross at trajectory line 5)"
    frames = ex.frames_by_line("frame,node,m00\n1,Arm,1\n1.5,Arm,1\n2,Arm,1\n2.5,Arm,1\n")
    assert frames == {2: 1.0, 3: 1.5, 4: 2.0, 5: 2.5}
    assert ex.clearance_lines(report, frames)[0]["line"] == "pin: CONTACT (Arm triangles cross at frame 2.5)"
    assert lines[2]["line"] == "lid: possible contact, clearance 0 to unknown"
    assert ex.clearance_lines({}) == []
