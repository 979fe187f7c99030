"""The folder exchange protocol of `sweptvol watch`, in plain Python (no bpy).

docs/exchange-protocol.md is the contract; this module is the add-on's side of it:
the protocol's file names (the one place the add-on spells them), job folders written as
`<job>.partial/` and renamed to `<job>/`, `job.json`, the trajectory CSV in the node + matrix
form, `status.json` and `report.json` reading, and the coordinate conversion between Blender
(Z up) and glTF (Y up). Starting and watching the daemon is `daemon.py`.

Matrices are 4x4 row-major lists of lists of floats, acting on column vectors: p' = M·p.
Everything here is tested by `blender_addon/tests/test_exchange.py` without Blender.
"""

import json
import math
import os
import re
import struct
import time

# ---------------------------------------------------------------------------------------------
# Small 4x4 algebra (no numpy: this module must import anywhere)

# The glTF exporter maps Blender (x, y, z) to glTF (x, z, -y): p_gltf = C·p_blender.
C = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
C_T = [[C[j][i] for j in range(4)] for i in range(4)]  # = C⁻¹ (a rotation)

IDENTITY = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def transform_point(m, p):
    return tuple(m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3] for i in range(3))


def affine_inverse(m):
    """Inverse of an affine 4x4 matrix (last row 0 0 0 1); raises ValueError if singular."""
    a = [row[:3] for row in m[:3]]
    det = (
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    )
    scale = max(abs(x) for row in a for x in row) or 1.0
    if not math.isfinite(det) or abs(det) <= 1e-12 * scale**3:
        raise ValueError("the matrix is singular (a zero scale?)")
    inv = [[0.0] * 3 for _ in range(3)]
    for i in range(3):
        for j in range(3):
            # cofactor of a[j][i] (transposed adjugate)
            r = [k for k in range(3) if k != j]
            c = [k for k in range(3) if k != i]
            minor = a[r[0]][c[0]] * a[r[1]][c[1]] - a[r[0]][c[1]] * a[r[1]][c[0]]
            inv[i][j] = (-1) ** (i + j) * minor / det
    t = [m[0][3], m[1][3], m[2][3]]
    out = [inv[i] + [-sum(inv[i][k] * t[k] for k in range(3))] for i in range(3)]
    return out + [[0.0, 0.0, 0.0, 1.0]]


def blender_to_gltf(m):
    """A Blender-space transform as the same transform in glTF space: C·M·Cᵀ."""
    return matmul(matmul(C, m), C_T)


def gltf_point_to_blender(p):
    """glTF (x, y, z) -> Blender (x, -z, y): Cᵀ·p."""
    return (p[0], -p[2], p[1])


def trajectory_row(world_blender, exported_world_gltf):
    """The matrix row of the trajectory CSV for one object at one frame.

    The exporter writes the object's mesh in its own (local) space with the axes changed,
    u = C·v, and puts it under a node whose world matrix in the file is W (glTF space), so
    sweptvol sees the point W·u. At the frame the object's vertex v sits at M_f·v in Blender
    world space, that is C·M_f·v in glTF space. The row R must satisfy R·W·C·v = C·M_f·v for
    every v, hence R = C·M_f·Cᵀ·W⁻¹.

    W is read back from the exported file, so whatever pose the exporter chose (the frame-0
    trap) cancels out. If the exporter placed the node where Blender had the object at frame
    r, W = C·M_r·Cᵀ and R = C·M_f·M_r⁻¹·Cᵀ.
    """
    return matmul(blender_to_gltf(world_blender), affine_inverse(exported_world_gltf))


# ---------------------------------------------------------------------------------------------
# GLB reading: node world matrices (for the rows) and the result mesh (for the import)

GLB_MAGIC = 0x46546C67
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942


def read_glb(path):
    """(json dict, binary chunk bytes or b"") of a .glb file."""
    with open(path, "rb") as f:
        data = f.read()
    if len(data) < 20:
        raise ValueError(f"{path}: too short for a .glb file")
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != 2:
        raise ValueError(f"{path}: not a glTF 2.0 binary file")
    offset, doc, binary = 12, None, b""
    while offset + 8 <= min(length, len(data)):
        chunk_len, chunk_type = struct.unpack_from("<II", data, offset)
        chunk = data[offset + 8 : offset + 8 + chunk_len]
        if chunk_type == CHUNK_JSON and doc is None:
            doc = json.loads(chunk.decode("utf-8"))
        elif chunk_type == CHUNK_BIN and not binary:
            binary = chunk
        offset += 8 + chunk_len
    if doc is None:
        raise ValueError(f"{path}: no JSON chunk")
    return doc, binary


def node_local_matrix(node):
    """A glTF node's local matrix (row-major), from `matrix` (column-major) or T·R·S."""
    if "matrix" in node:
        m = node["matrix"]
        return [[float(m[c * 4 + r]) for c in range(4)] for r in range(4)]
    tx, ty, tz = node.get("translation", [0.0, 0.0, 0.0])
    qx, qy, qz, qw = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    sx, sy, sz = node.get("scale", [1.0, 1.0, 1.0])
    r = [
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ]
    s, t = (sx, sy, sz), (tx, ty, tz)
    return [[r[i][j] * s[j] for j in range(3)] + [t[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]


def _mesh_nodes(doc):
    """(node, world matrix) for every node with a mesh in the default scene (else the first
    scene; without scenes, every root), in traversal order."""
    nodes = doc.get("nodes", [])
    scenes = doc.get("scenes", [])
    if scenes:
        roots = scenes[doc.get("scene", 0)].get("nodes", [])
    else:
        children = {c for n in nodes for c in n.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    stack = [(i, IDENTITY) for i in reversed(roots)]
    while stack:
        i, parent = stack.pop()
        node = nodes[i]
        world = matmul(parent, node_local_matrix(node))
        if "mesh" in node:
            yield node, world
        stack.extend((c, world) for c in reversed(node.get("children", [])))


def mesh_node_worlds(doc):
    """[(node name, world matrix)]: where the file puts each mesh node, what sweptvol reads
    as the generator's parts before any row moves them."""
    return [(node.get("name", ""), world) for node, world in _mesh_nodes(doc)]


_COMPONENT = {5120: ("b", 1), 5121: ("B", 1), 5122: ("h", 2), 5123: ("H", 2), 5125: ("I", 4), 5126: ("f", 4)}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def _accessor(doc, binary, index):
    acc = doc["accessors"][index]
    fmt, size = _COMPONENT[acc["componentType"]]
    width = _WIDTH[acc["type"]]
    count = acc["count"]
    if "bufferView" not in acc:
        return [tuple([0] * width)] * count
    view = doc["bufferViews"][acc["bufferView"]]
    if view.get("buffer", 0) != 0:
        raise ValueError("only the GLB's own buffer is supported")
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride") or size * width
    return [struct.unpack_from("<" + fmt * width, binary, start + k * stride) for k in range(count)]


def read_glb_mesh(path):
    """The triangles of every mesh node of a .glb, in glTF world space: (points, triangles).

    Enough for sweptvol's own output (indexed or not, TRIANGLES mode); other primitive modes
    are skipped."""
    doc, binary = read_glb(path)
    points, tris = [], []
    for node, world in _mesh_nodes(doc):
        for prim in doc["meshes"][node["mesh"]].get("primitives", []):
            if prim.get("mode", 4) != 4:
                continue
            pos = _accessor(doc, binary, prim["attributes"]["POSITION"])
            base = len(points)
            points.extend(transform_point(world, p) for p in pos)
            if "indices" in prim:
                idx = [i[0] for i in _accessor(doc, binary, prim["indices"])]
            else:
                idx = list(range(len(pos)))
            tris.extend((base + idx[k], base + idx[k + 1], base + idx[k + 2])
                        for k in range(0, len(idx) - 2, 3))
    return points, tris


def write_glb(doc, binary):
    """The bytes of a .glb holding `doc` (a dict) and the binary chunk `binary`."""
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(text), CHUNK_JSON) + text
    if binary:
        chunks += struct.pack("<II", len(binary), CHUNK_BIN) + binary
    return struct.pack("<III", GLB_MAGIC, 2, 12 + len(chunks)) + chunks


def column_major(m):
    """A row-major 4x4 as glTF's `matrix` (column-major, 16 numbers)."""
    return [float(m[r][c]) for c in range(4) for r in range(4)]


def rig_document(doc, tree):
    """The exported document with its nodes replaced by the kinematic tree `tree`: a list of
    (name, parent index into `tree` or None, local matrix at the export frame in glTF space,
    name of the exported mesh node it holds or None), parents first. Each tree node keeps the
    mesh of the exported node of that name; the exporter's own nodes, skins and animations go
    (their indices no longer hold). The daemon reads it with rows in parent space (job.json
    `rows: "local"`), each row setting one node's transform relative to its parent."""
    meshes = {n.get("name"): n["mesh"] for n in doc.get("nodes", []) if "mesh" in n}
    nodes = []
    for i, (name, parent, local, mesh) in enumerate(tree):
        if parent is not None and not 0 <= parent < i:
            raise ValueError(f"the parent of '{name}' does not come before it")
        node = {"name": name, "matrix": column_major(local)}
        if mesh is not None:
            if mesh not in meshes:
                raise ValueError(f"the glTF exporter wrote no mesh node named '{mesh}'")
            node["mesh"] = meshes[mesh]
        nodes.append(node)
    for i, (_, parent, _, _) in enumerate(tree):
        if parent is not None:
            nodes[parent].setdefault("children", []).append(i)
    out = {k: v for k, v in doc.items() if k not in ("nodes", "scenes", "scene", "skins", "animations")}
    out["nodes"] = nodes
    out["scenes"] = [{"nodes": [i for i, t in enumerate(tree) if t[1] is None]}]
    out["scene"] = 0
    return out


# ---------------------------------------------------------------------------------------------
# Trajectory CSV (node + matrix form, see src/io/trajectory.rs)

MATRIX_COLUMNS = [f"m{r}{c}" for r in range(4) for c in range(4)]


def csv_field(text):
    """A CSV field for a node name: quoted when it holds a comma, a quote or edge spaces."""
    if "\n" in text or "\r" in text:
        raise ValueError(f"the name {text!r} holds a line break, which a CSV row cannot carry")
    if not text:
        raise ValueError("a node name is empty")
    if any(ch in text for ch in ',"') or text != text.strip():
        return '"' + text.replace('"', '""') + '"'
    return text


def _number(x):
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"a matrix entry is not finite ({x})")
    return repr(x + 0.0)  # shortest round-trip text; -0.0 becomes 0.0


def trajectory_csv(rows, local=False):
    """CSV text for rows of (frame, node name, 4x4 matrix in glTF space): world-space rows, or
    with `local` each node's transform relative to its parent (job.json `rows: "local"`)."""
    what = ("sets the node's transform relative to its parent at that frame (glTF space)" if local
            else "maps the node as exported to its placement at that frame (glTF space)")
    lines = [f"# written by the sweptvol Blender add-on: each row {what}",
             ",".join(["frame", "node"] + MATRIX_COLUMNS)]
    for frame, node, m in rows:
        values = [m[r][c] for r in range(4) for c in range(4)]
        lines.append(",".join([_number(frame), csv_field(node)] + [_number(v) for v in values]))
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------
# Job folders

# The protocol's names, the add-on's one copy of them (docs/exchange-protocol.md; the Rust side
# is src/watch/protocol.rs, and `sweptvol protocol` prints them: tests/test_protocol_names.py
# compares the two). Nothing else in the add-on spells a protocol file name.

PARTIAL_SUFFIX = ".partial"  # a job folder being written; renaming it without the suffix commits
CONTROL_DIR = ".sweptvol"  # the daemon's own folder in the watched one
HEARTBEAT = "daemon.json"  # in CONTROL_DIR: the daemon's heartbeat

# What a client writes into a job folder
GENERATOR_GLB = "generator.glb"
GENERATOR_GLTF = "generator.gltf"  # the other accepted generator form (the add-on writes .glb)
TRAJECTORY = "trajectory.csv"
JOB_JSON = "job.json"
CANCEL = "cancel"
# The add-on's own record of its adaptive sampling (sampling.py): the daemon never reads it.
SAMPLING = "sampling.json"
OBSTACLES_GLB = "obstacles.glb"  # the add-on's obstacle objects, one node each (job.json `against`)

# What the daemon writes there
MESH = "swept.glb"
START_MESH = "start.glb"
REPORT = "report.json"
CLEARANCE_MAP = "clearance.glb"  # <obstacle file stem>.clearance.glb, one per job.json `against`
STATUS = "status.json"
DEPTH_IMAGES = tuple(f"depth-{a}{s}.exr" for a in "xyz" for s in ("min", "max"))
ALSO_OUTPUTS = {"stl": "swept.stl", "ply": "swept.ply", "obj": "swept.obj"}  # job.json `also`

JOB_KEYS = ("resolution", "tolerance", "delta", "epsilon", "backend", "name", "motion",
            "target_triangles", "keep_start_mesh", "also", "classify", "radii", "against",
            "require_clearance", "clearance_scale", "relative_to", "rows",
            "package_dir")
MOTIONS = ("screw", "discrete")  # job.json `motion`: the motion between rows covered, or not
CLASSIFY_METHODS = ("auto", "flood", "axes")  # job.json `classify`: hidden pockets opened or not
RADII = ("exact", "paper")  # job.json `radii`: δ and ε (sampling.py assumes the default, exact)
STATES = ("queued", "running", "done", "failed", "cancelled")  # status.json `state`
FINISHED = ("done", "failed", "cancelled")


def job_name(base, folder, now=None):
    """A fresh job folder name from `base` (e.g. the objects' names): safe characters, not
    starting with `.`, not ending with `.partial`, not present in `folder` in either form."""
    stem = re.sub(r"[^A-Za-z0-9_-]+", "-", base).strip("-.")[:40] or "job"
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now if now is not None else time.time()))
    name = f"{stem}-{stamp}"
    for k in range(1, 10000):
        candidate = name if k == 1 else f"{name}-{k}"
        if not any(os.path.lexists(os.path.join(folder, candidate + s)) for s in ("", PARTIAL_SUFFIX)):
            return candidate
    raise RuntimeError("no free job name")


def job_options(**options):
    """The `job.json` object: drops None values, refuses unknown keys and both accuracies."""
    opts = {k: v for k, v in options.items() if v is not None}
    unknown = sorted(set(opts) - set(JOB_KEYS))
    if unknown:
        raise ValueError(f"unknown job option(s) {', '.join(unknown)}")
    if "resolution" in opts and "tolerance" in opts:
        raise ValueError("give either a resolution or a tolerance, not both")
    if "resolution" in opts and (not isinstance(opts["resolution"], int) or opts["resolution"] < 1):
        raise ValueError("the resolution must be a positive integer")
    if "tolerance" in opts and not (float(opts["tolerance"]) > 0 and math.isfinite(opts["tolerance"])):
        raise ValueError("the tolerance must be a positive number")
    if opts.get("backend", "auto") not in ("auto", "gpu", "cpu"):
        raise ValueError("the backend must be auto, gpu or cpu")
    if opts.get("motion", "screw") not in MOTIONS:
        raise ValueError("the motion must be screw or discrete")
    return opts


def begin_job(folder, name):
    """Create `folder/<name>.partial/` (exclusively) and return its path."""
    if name.startswith(".") or name.endswith(PARTIAL_SUFFIX) or "/" in name or os.sep in name:
        raise ValueError(f"{name!r} is not a valid job name")
    if os.path.lexists(os.path.join(folder, name)):
        raise FileExistsError(f"a job named {name} already exists in {folder}")
    partial = os.path.join(folder, name + PARTIAL_SUFFIX)
    os.mkdir(partial)
    return partial


def _write_file(path, data):
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def write_job_inputs(partial, csv_text, options, sampling=None):
    """Write trajectory.csv and job.json into a `.partial` folder (generator.glb is written by
    the exporter beside them), and the sampling record as sampling.json when there is one."""
    _write_file(os.path.join(partial, TRAJECTORY), csv_text.encode("utf-8"))
    job_json = json.dumps(job_options(**options), indent=1) + "\n"
    _write_file(os.path.join(partial, JOB_JSON), job_json.encode())
    if sampling is not None:
        text = json.dumps(sampling, indent=1, allow_nan=False) + "\n"
        _write_file(os.path.join(partial, SAMPLING), text.encode())


def commit_job(partial):
    """Rename `<job>.partial/` to `<job>/`: the commit. Returns the job folder."""
    if not partial.endswith(PARTIAL_SUFFIX):
        raise ValueError(f"{partial} is not a .partial folder")
    for name in (GENERATOR_GLB, TRAJECTORY):
        if not os.path.isfile(os.path.join(partial, name)):
            raise FileNotFoundError(f"{partial} has no {name}")
    final = partial[: -len(PARTIAL_SUFFIX)]
    if os.path.lexists(final):
        raise FileExistsError(f"{final} already exists")
    os.rename(partial, final)
    return final


def abandon_job(partial):
    """Remove a `.partial` folder that will not be committed (the daemon never reads it)."""
    if partial and partial.endswith(PARTIAL_SUFFIX) and os.path.isdir(partial):
        for name in os.listdir(partial):
            os.remove(os.path.join(partial, name))
        os.rmdir(partial)


def request_cancel(job_dir):
    """Create the `cancel` file in a job folder."""
    with open(os.path.join(job_dir, CANCEL), "a"):
        pass


def read_json(path):
    """A JSON object from a file, or None if it is missing or not (yet) an object."""
    try:
        with open(path, "rb") as f:
            value = json.loads(f.read().decode("utf-8"))
    except (OSError, ValueError):
        return None
    return value if isinstance(value, dict) else None


def read_status(job_dir):
    """`status.json` of a job folder as a dict (None while there is none)."""
    return read_json(os.path.join(job_dir, STATUS))


def read_sampling(job_dir):
    """The add-on's sampling record of a job (sampling.json), or None."""
    return read_json(os.path.join(job_dir, SAMPLING))


def read_report(job_dir):
    return read_json(os.path.join(job_dir, REPORT))


# The panel fields that set job.json keys. The daemon names a bad option value by its key
# (status.json `error.column`, and `"key"` in `error.message`); the panel words it by the field.
PANEL_FIELDS = {"resolution": "Resolution", "tolerance": "Tolerance"}


def failure_text(status):
    """Why a job failed, in the panel's terms: a bad value of a panel field is named by the
    field (the daemon's `"tolerance"` becomes Tolerance), with the fix in the panel."""
    error = (status or {}).get("error") or {}
    key = error.get("column")
    if os.path.basename(str(error.get("file") or "")) == JOB_JSON and key in PANEL_FIELDS:
        text = str(error.get("message") or "")
        for k, label in PANEL_FIELDS.items():
            text = text.replace(f'"{k}"', label)
        return f"{text} (fix: change {PANEL_FIELDS[key]} in the Swept Volume panel)"
    return (status or {}).get("message", "")


def describe_status(status):
    """One line for the panel and the status bar."""
    if status is None:
        return "waiting for the daemon"
    state = status.get("state", "?")
    if state == "running":
        pct = 100.0 * float(status.get("progress") or 0.0)
        return f"running: {status.get('stage') or ''} {pct:.0f}%"
    if state == "failed" and status.get("message"):
        return f"failed: {failure_text(status)}"
    if state == "cancelled" and status.get("message"):
        return f"cancelled: {status['message']}"
    return state


def result_summary(report, sampling=None):
    """The custom properties put on the imported mesh: the guarantee and the counts, and with a
    sampling record (sampling.json) how far Blender's motion strayed from the continuous motion
    the sweep covers at the checked sub-frames."""
    mesh = report.get("mesh", {}) if report else {}
    counts = report.get("counts", {}) if report else {}
    params = report.get("parameters", {}) if report else {}
    out = {}
    for key, value in (
        ("sweptvol_hausdorff_bound", mesh.get("hausdorff_bound")),
        ("sweptvol_clearance", mesh.get("clearance")),
        ("sweptvol_voxel_size", params.get("voxel_size")),
        ("sweptvol_volume", mesh.get("volume")),
        ("sweptvol_triangles", mesh.get("triangles_final")),
        ("sweptvol_vertices", mesh.get("vertices")),
        ("sweptvol_poses", counts.get("poses")),
        ("sweptvol_posed_triangles", counts.get("posed_triangles")),
        ("sweptvol_generator_triangles", counts.get("triangles")),
        ("sweptvol_resolution", report.get("resolution") if report else None),
        ("sweptvol_version", report.get("sweptvol_version") if report else None),
        ("sweptvol_motion", (report.get("motion") or {}).get("model") if report else None),
        ("sweptvol_sampling_deviation", (sampling or {}).get("worst_deviation")),
        ("sweptvol_sampling_threshold", (sampling or {}).get("threshold")),
        ("sweptvol_sampling_finest_step", (sampling or {}).get("finest_step")),
        ("sweptvol_sampling_rows_added", (sampling or {}).get("rows_added")),
        ("sweptvol_sampling_probes", (sampling or {}).get("probes")),
        ("sweptvol_sampling_unresolved", (sampling or {}).get("unresolved")),
    ):
        if isinstance(value, list):
            value = [v for v in value]
        if value is not None:
            out[key] = value
    return out


def read_clearance_map(path):
    """The obstacles of a clearance map (NAME.clearance.glb), in glTF world space: a list of
    {"name", "points", "tris", "values" (the clearance's lower end per vertex), "colours",
    "closest" ((on the obstacle, on the swept volume) or None), "extras"}."""
    doc, binary = read_glb(path)
    out = []
    nodes = doc.get("nodes", [])
    for node, world in _mesh_nodes(doc):
        mesh = doc["meshes"][node["mesh"]]
        prims = [p for p in mesh.get("primitives", []) if p.get("mode", 4) == 4]
        if not prims or "_CLEARANCE" not in prims[0].get("attributes", {}):
            continue
        prim = prims[0]
        attrs = prim["attributes"]
        pos = [transform_point(world, p) for p in _accessor(doc, binary, attrs["POSITION"])]
        idx = [i[0] for i in _accessor(doc, binary, prim["indices"])]
        closest = None
        for child in node.get("children", []):
            line = doc["meshes"][nodes[child]["mesh"]]["primitives"][0]
            ends = _accessor(doc, binary, line["attributes"]["POSITION"])
            if len(ends) == 2:
                closest = (transform_point(world, ends[0]), transform_point(world, ends[1]))
        out.append({
            "name": node.get("name", ""),
            "points": pos,
            "tris": [tuple(idx[k:k + 3]) for k in range(0, len(idx) - 2, 3)],
            "values": [v[0] for v in _accessor(doc, binary, attrs["_CLEARANCE"])],
            "colours": [tuple(c[:3]) for c in _accessor(doc, binary, attrs["COLOR_0"])],
            "closest": closest,
            "extras": node.get("extras", {}),
        })
    return out


VERDICT_WORDS = {"clear": "clear", "possible-contact": "possible contact", "contact": "CONTACT"}


def frames_by_line(csv_text):
    """{CSV line number: frame} of a trajectory.csv the add-on wrote (frame first)."""
    out = {}
    for number, text in enumerate(csv_text.splitlines(), start=1):
        head = text.split(",", 1)[0]
        try:
            out[number] = float(head)
        except ValueError:
            continue
    return out


def clearance_lines(report, frames=None):
    """One entry per obstacle of the report's clearance section: {"name", "verdict", "lower",
    "upper", "map", "line"} with `line` the panel's text, and the contacts first. `frames`
    ({CSV line: frame}, `frames_by_line`) names a contact's frame."""
    section = (report or {}).get("clearance") or {}
    out = []
    for o in section.get("obstacles", []):
        verdict = o.get("verdict", "")
        lower, upper = o.get("lower"), o.get("upper")
        upper_text = "unknown" if upper is None else f"{upper:.4g}"
        line = f"{o.get('name', '')}: {VERDICT_WORDS.get(verdict, verdict)}"
        if verdict == "contact":
            w = o.get("witness") or {}
            frame = (frames or {}).get(w.get("line"))
            if frame is not None:
                at = f" at frame {frame:g}"
            elif w.get("line") is not None:
                at = f" at trajectory line {w['line']}"
            else:
                at = ""
            line += f" ({w.get('part', 'the part')} {w.get('how', 'meets it')}{at})"
        else:
            line += f", clearance {lower:.4g} to {upper_text}"
        out.append({"name": o.get("name", ""), "verdict": verdict, "lower": lower,
                    "upper": upper, "map": o.get("map", ""), "line": line})
    out.sort(key=lambda e: e["verdict"] != "contact")
    return out
