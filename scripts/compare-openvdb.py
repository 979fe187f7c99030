#!/usr/bin/python3
"""Baseline for docs/benchmarks.md: the swept volume by OpenVDB's level-set union.

Run with the system Python and Debian's python3-openvdb (kept out of .ci/run):

    /usr/bin/python3 scripts/compare-openvdb.py GENERATOR.glb TRAJECTORY.csv --voxel H --out OUT.glb

Poses every generator triangle (glTF node transforms, then each CSV row's pose: translation and
unit quaternion columns tx..qz, or a 4x4 matrix m00..m33; one part, no node column), converts the
triangle soup to a narrow-band level set with voxel size H (meshToVolume), and extracts the
isosurface at √3·H (volumeToMesh), which should enclose the soup. Writes the mesh as a .glb that
`sweptvol verify` reads, and prints the timing and triangle count as JSON.
"""

import argparse
import json
import math
import struct
import sys
import time

import numpy as np
import pyopenvdb as vdb


def read_glb(path):
    """World-space positions (n, 3) float64 and triangles (m, 3) of every triangle primitive."""
    data = open(path, "rb").read()
    magic, _version, _length = struct.unpack_from("<III", data, 0)
    if magic != 0x46546C67:
        sys.exit(f"{path}: not a binary glTF (.glb) file")
    jlen, _ = struct.unpack_from("<II", data, 12)
    gltf = json.loads(data[20 : 20 + jlen])
    blen, _ = struct.unpack_from("<II", data, 20 + jlen)
    blob = data[28 + jlen : 28 + jlen + blen]

    def accessor(i):
        a = gltf["accessors"][i]
        view = gltf["bufferViews"][a["bufferView"]]
        dtype = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}[a["componentType"]]
        width = {"SCALAR": 1, "VEC3": 3}[a["type"]]
        start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
        stride = view.get("byteStride", 0)
        item = np.dtype(dtype).itemsize * width
        if stride and stride != item:
            rows = [np.frombuffer(blob, dtype, width, start + k * stride) for k in range(a["count"])]
            return np.array(rows)
        return np.frombuffer(blob, dtype, a["count"] * width, start).reshape(a["count"], width)

    def local(node):
        if "matrix" in node:
            return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
        t = np.eye(4)
        x, y, z, w = node.get("rotation", [0, 0, 0, 1])
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        t[:3, :3] = r * np.array(node.get("scale", [1, 1, 1]))
        t[:3, 3] = node.get("translation", [0, 0, 0])
        return t

    positions, triangles = [], []

    def visit(i, parent):
        node = gltf["nodes"][i]
        world = parent @ local(node)
        if "mesh" in node:
            for prim in gltf["meshes"][node["mesh"]]["primitives"]:
                if prim.get("mode", 4) != 4:
                    continue
                p = accessor(prim["attributes"]["POSITION"]).astype(np.float64)
                p = p @ world[:3, :3].T + world[:3, 3]
                idx = accessor(prim["indices"]).reshape(-1, 3) if "indices" in prim else np.arange(len(p)).reshape(-1, 3)
                base = sum(len(q) for q in positions)
                positions.append(p)
                triangles.append(idx.astype(np.int64) + base)
        for c in node.get("children", []):
            visit(c, world)

    scene = gltf["scenes"][gltf.get("scene", 0)]
    for i in scene["nodes"]:
        visit(i, np.eye(4))
    return np.concatenate(positions), np.concatenate(triangles)


def read_poses(path):
    """4x4 pose matrices from a sweptvol trajectory CSV (one part)."""
    rows = [l.strip() for l in open(path) if l.strip() and not l.lstrip().startswith("#")]
    header = [h.strip() for h in rows[0].split(",")]
    col = {h: i for i, h in enumerate(header)}
    poses = []
    for line in rows[1:]:
        v = [x.strip() for x in line.split(",")]
        m = np.eye(4)
        if "m00" in col:
            for r in range(4):
                for c in range(4):
                    m[r, c] = float(v[col[f"m{r}{c}"]])
        else:
            w, x, y, z = (float(v[col[k]]) for k in ("qw", "qx", "qy", "qz"))
            n = math.sqrt(w * w + x * x + y * y + z * z)
            w, x, y, z = w / n, x / n, y / n, z / n
            m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
            m[:3, 3] = [float(v[col[k]]) for k in ("tx", "ty", "tz")]
        poses.append(m)
    return poses


def write_glb(path, points, tris):
    pos = np.ascontiguousarray(points, dtype=np.float32)
    idx = np.ascontiguousarray(tris, dtype=np.uint32)
    blob = pos.tobytes() + idx.tobytes()
    gltf = {
        "asset": {"version": "2.0", "generator": "sweptvol scripts/compare-openvdb.py"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes},
                        {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": idx.nbytes}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
             "min": pos.min(axis=0).tolist(), "max": pos.max(axis=0).tolist()},
            {"bufferView": 1, "componentType": 5125, "count": idx.size, "type": "SCALAR"},
        ],
    }
    j = json.dumps(gltf).encode()
    j += b" " * (-len(j) % 4)
    with open(path, "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, 28 + len(j) + len(blob)))
        f.write(struct.pack("<II", len(j), 0x4E4F534A) + j)
        f.write(struct.pack("<II", len(blob), 0x004E4942) + blob)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("generator")
    ap.add_argument("trajectory")
    ap.add_argument("--voxel", type=float, required=True, help="voxel size h, world units")
    ap.add_argument("--out", required=True, help="output .glb")
    a = ap.parse_args()

    t0 = time.perf_counter()
    p, t = read_glb(a.generator)
    poses = read_poses(a.trajectory)
    soup_p = np.concatenate([p @ m[:3, :3].T + m[:3, 3] for m in poses]).astype(np.float32)
    soup_t = np.concatenate([t + k * len(p) for k in range(len(poses))]).astype(np.int32)
    t1 = time.perf_counter()
    iso = math.sqrt(3.0) * a.voxel
    xform = vdb.createLinearTransform(voxelSize=a.voxel)
    # Narrow band wide enough to hold the isovalue (in voxels) with a margin.
    grid = vdb.FloatGrid.createLevelSetFromPolygons(
        soup_p, triangles=soup_t, transform=xform, halfWidth=math.sqrt(3.0) + 2.0)
    t2 = time.perf_counter()
    points, tris, quads = grid.convertToPolygons(isovalue=iso, adaptivity=0.0)
    tris = np.concatenate([tris.reshape(-1, 3),
                           quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]) if len(quads) else tris
    # Orient outward (glTF: counter-clockwise seen from outside): flip when the signed volume
    # comes out negative.
    tris = np.asarray(tris, dtype=np.int64)
    v = np.asarray(points, dtype=np.float64)[tris]
    if np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() < 0:
        tris = tris[:, ::-1]
    t3 = time.perf_counter()
    write_glb(a.out, points, tris)
    print(json.dumps({
        "posed_triangles": int(len(soup_t)),
        "voxel": a.voxel,
        "isovalue": iso,
        "triangles": int(len(tris)),
        "seconds": {"read_and_pose": t1 - t0, "mesh_to_volume": t2 - t1,
                    "volume_to_mesh": t3 - t2, "total": t3 - t0},
    }, indent=1))


if __name__ == "__main__":
    main()
