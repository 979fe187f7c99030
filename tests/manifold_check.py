"""Independent check that .glb meshes are what downstream tools accept as solids.

For each file (one triangle primitive, as sweptvol writes), with the vertices exactly as stored
(no merging, no repair):
- its own count: every edge in exactly two triangles of opposite directions, every vertex's
  triangles one closed fan, no two vertices at one position;
- trimesh: `is_watertight` and `is_volume`;
- manifold3d: a `Manifold` builds from the mesh without error and a box through its centre
  subtracts from it, leaving a non-empty solid smaller than the original.

Prints one line per file and exits 1 if any file fails (0 if all pass). Used by
tests/manifold_tools.rs, which also feeds it a pinched mesh that must fail.
"""

import json
import struct
import sys
from collections import defaultdict

import manifold3d
import numpy as np
import trimesh

COMPONENT = {5126: ("f", 4), 5125: ("I", 4), 5123: ("H", 2), 5121: ("B", 1)}
WIDTH = {"SCALAR": 1, "VEC3": 3}


def read_glb(path):
    data = open(path, "rb").read()
    magic, _version, _length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF", f"{path}: not a .glb"
    json_len, _ = struct.unpack_from("<I4s", data, 12)
    doc = json.loads(data[20 : 20 + json_len])
    bin_start = 20 + json_len + 8
    binary = data[bin_start:]

    def accessor(i):
        acc = doc["accessors"][i]
        view = doc["bufferViews"][acc["bufferView"]]
        fmt, size = COMPONENT[acc["componentType"]]
        n = acc["count"] * WIDTH[acc["type"]]
        off = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        values = struct.unpack_from(f"<{n}{fmt}", binary, off)
        return np.array(values).reshape(acc["count"], WIDTH[acc["type"]])

    (prim,) = [p for m in doc["meshes"] for p in m["primitives"]]
    positions = accessor(prim["attributes"]["POSITION"]).astype(np.float64)
    faces = accessor(prim["indices"]).reshape(-1, 3).astype(np.int64)
    return positions, faces


def own_defects(positions, faces):
    """(bad edges, pinched vertices, duplicate positions), counted without any library."""
    uses = defaultdict(lambda: [0, 0])
    corners = defaultdict(list)
    for a, b, c in faces.tolist():
        for u, v, w in ((a, b, c), (b, c, a), (c, a, b)):
            uses[(min(u, v), max(u, v))][0 if u < v else 1] += 1
            corners[u].append((v, w))  # corner at u: next v, previous w
    bad_edges = sum(1 for e in uses.values() if e != [1, 1])
    pinched = 0
    for fan in corners.values():
        at, steps = 0, 0
        while True:
            nxt = [k for k, (n, _) in enumerate(fan) if n == fan[at][1]]
            if not nxt:
                pinched += 1
                break
            at, steps = nxt[0], steps + 1
            if at == 0 or steps > len(fan):
                pinched += not (at == 0 and steps == len(fan))
                break
    duplicates = len(positions) - len({tuple(p) for p in positions.tolist()})
    return bad_edges, pinched, duplicates


def check(path):
    positions, faces = read_glb(path)
    problems = []
    edges, pinched, duplicates = own_defects(positions, faces)
    if edges or pinched or duplicates:
        problems.append(
            f"own count: {edges} bad edges, {pinched} pinched vertices, {duplicates} duplicate positions"
        )
    mesh = trimesh.Trimesh(vertices=positions, faces=faces, process=False)
    if not mesh.is_watertight:
        problems.append("trimesh: not watertight")
    if not mesh.is_volume:
        problems.append("trimesh: not a volume")
    solid = manifold3d.Manifold(
        manifold3d.Mesh(vert_properties=positions.astype(np.float32), tri_verts=faces.astype(np.uint32))
    )
    status = solid.status()
    if status != manifold3d.Error.NoError:
        problems.append(f"manifold3d: {status}")
    else:
        lo, hi = positions.min(axis=0), positions.max(axis=0)
        size = (hi - lo) * np.array([0.5, 0.5, 2.0])
        centre = (lo + hi) / 2
        box = manifold3d.Manifold.cube(size.tolist(), center=True).translate(centre.tolist())
        cut = solid - box
        before, after = solid.volume(), cut.volume()
        if cut.status() != manifold3d.Error.NoError or not (0 < after < before):
            problems.append(f"manifold3d: box subtraction gave volume {after} from {before}")
    verdict = "PASS" if not problems else "FAIL: " + "; ".join(problems)
    print(f"{path}: {len(faces)} triangles: {verdict}", flush=True)
    return not problems


if __name__ == "__main__":
    results = [check(p) for p in sys.argv[1:]]
    sys.exit(0 if results and all(results) else 1)
