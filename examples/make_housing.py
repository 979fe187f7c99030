"""Write examples/bunny-housing.glb: an open housing around the bundled bunny's vibration
(a floor and four walls, each its own node, 48 x 48 quads), at gaps of about 0.3 to 0.9 from
the swept volume, for `sweptvol run --against` and `sweptvol clearance` (README, "Clearance").

    python3 examples/make_housing.py
"""

import json
import os
import struct


def plate(origin, u, v, n=48):
    """A grid of n x n quads: corner `origin`, edges `u` and `v`; positions and triangles."""
    pos = [[origin[k] + u[k] * i / n + v[k] * j / n for k in range(3)]
           for j in range(n + 1) for i in range(n + 1)]
    tris = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            tris += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    return pos, tris


def glb(parts):
    bin_, acc, views, meshes, nodes = b"", [], [], [], []
    for k, (name, pos, tris) in enumerate(parts):
        lo = [min(p[c] for p in pos) for c in range(3)]
        hi = [max(p[c] for p in pos) for c in range(3)]
        at = len(bin_)
        bin_ += b"".join(struct.pack("<3f", *p) for p in pos)
        ia = len(bin_)
        bin_ += b"".join(struct.pack("<3I", *t) for t in tris)
        views += [{"buffer": 0, "byteOffset": at, "byteLength": ia - at, "target": 34962},
                  {"buffer": 0, "byteOffset": ia, "byteLength": len(bin_) - ia, "target": 34963}]
        acc += [{"bufferView": 2 * k, "componentType": 5126, "count": len(pos), "type": "VEC3",
                 "min": lo, "max": hi},
                {"bufferView": 2 * k + 1, "componentType": 5125, "count": 3 * len(tris),
                 "type": "SCALAR"}]
        meshes.append({"name": name, "primitives": [{"attributes": {"POSITION": 2 * k},
                                                      "indices": 2 * k + 1}]})
        nodes.append({"name": name, "mesh": k})
    doc = {"asset": {"version": "2.0", "generator": "examples/make_housing.py"}, "scene": 0,
           "scenes": [{"nodes": list(range(len(parts)))}], "nodes": nodes, "meshes": meshes,
           "accessors": acc, "bufferViews": views, "buffers": [{"byteLength": len(bin_)}]}
    j = json.dumps(doc, separators=(",", ":")).encode()
    j += b" " * (-len(j) % 4)
    bin_ += b"\0" * (-len(bin_) % 4)
    total = 12 + 8 + len(j) + 8 + len(bin_)
    return (b"glTF" + struct.pack("<II", 2, total) + struct.pack("<I", len(j)) + b"JSON" + j
            + struct.pack("<I", len(bin_)) + b"BIN\0" + bin_)


if __name__ == "__main__":
    x0, x1, y0, y1, z0, z1 = -5.6, 6.0, -0.5, 11.0, -5.0, 4.6
    parts = [
        ("floor", *plate([x0, y0, z0], [x1 - x0, 0, 0], [0, 0, z1 - z0])),
        ("wall-west", *plate([x0, y0, z0], [0, 0, z1 - z0], [0, y1 - y0, 0])),
        ("wall-east", *plate([x1, y0, z0], [0, y1 - y0, 0], [0, 0, z1 - z0])),
        ("wall-north", *plate([x0, y0, z0], [0, y1 - y0, 0], [x1 - x0, 0, 0])),
        ("wall-south", *plate([x0, y0, z1], [x1 - x0, 0, 0], [0, y1 - y0, 0])),
    ]
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "bunny-housing.glb")
    with open(out, "wb") as f:
        f.write(glb(parts))
    print(out, sum(len(t) for _, _, t in parts), "triangles")
