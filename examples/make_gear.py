"""Write examples/gear.glb: a closed spur gear of the bunny's footprint (20 teeth, outer radius
5, root radius 4.2, bore radius 1.5, 3 thick along y, resting on y = 0), for the issue-26 case
"a gear along an assembly path, 200 poses" (docs/benchmarks.md): swept along
examples/bunny-assembly.csv like the bunny.

    python3 examples/make_gear.py [--out PATH]
"""

import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from make_housing import glb  # noqa: E402

TEETH, R_TIP, R_ROOT, R_BORE, THICK = 20, 5.0, 4.2, 1.5, 3.0


def profile():
    """The outer outline as (angle, radius) points by increasing angle (x = r cos a,
    z = -r sin a): per tooth a root arc, a flank up, a tip arc of a fifth of the pitch and a
    flank down; star-shaped about the axis, so each ray from it meets the outline once."""
    pts = []
    pitch = 2 * math.pi / TEETH
    # fractions of the pitch: root arc 0..0.3, rising flank to 0.4, tip 0.4..0.6, falling to 0.7,
    # root again 0.7..1 (the next tooth's root arc starts where this one's ends)
    marks = [(0.0, R_ROOT), (0.15, R_ROOT), (0.3, R_ROOT), (0.4, R_TIP), (0.5, R_TIP),
             (0.6, R_TIP), (0.7, R_ROOT), (0.85, R_ROOT)]
    for k in range(TEETH):
        for f, r in marks:
            a = (k + f) * pitch
            pts.append((a, r))
    return pts


def gear():
    """Positions and triangles of the closed gear, faces outward: two annuli between the
    outline and the bore, zipped by angle, and the two side walls."""
    outer = profile()
    bore = [(2 * math.pi * i / 80, R_BORE) for i in range(80)]
    pos = []

    def ring(points, y):
        at = len(pos)
        for a, r in points:
            pos.append([r * math.cos(a), y, -r * math.sin(a)])
        return at

    o0, o1 = ring(outer, 0.0), ring(outer, THICK)
    b0, b1 = ring(bore, 0.0), ring(bore, THICK)
    no, nb = len(outer), len(bore)
    tris = []
    # the two annuli: zip the outline and the bore by angle (both run counter-clockwise from +x,
    # seen from +y; x = r cos a, z = -r sin a)
    i = j = 0
    while i < no or j < nb:
        ai = outer[i % no][0] + (2 * math.pi if i >= no else 0)
        aj = bore[j % nb][0] + (2 * math.pi if j >= nb else 0)
        take_outer = j >= nb or (i < no and ai <= aj)
        if take_outer:
            a, b, c = o1 + i % no, o1 + (i + 1) % no, b1 + j % nb
            tris.append([a, b, c])  # top, normal +y
            tris.append([o0 + i % no, b0 + j % nb, o0 + (i + 1) % no])
            i += 1
        else:
            a, b, c = b1 + j % nb, o1 + i % no, b1 + (j + 1) % nb
            tris.append([a, b, c])
            tris.append([b0 + j % nb, b0 + (j + 1) % nb, o0 + i % no])
            j += 1
    # the sides: the outline facing out, the bore facing in
    for k in range(no):
        a, b = k, (k + 1) % no
        tris += [[o0 + a, o0 + b, o1 + b], [o0 + a, o1 + b, o1 + a]]
    for k in range(nb):
        a, b = k, (k + 1) % nb
        tris += [[b0 + a, b1 + b, b0 + b], [b0 + a, b1 + a, b1 + b]]
    return pos, tris


if __name__ == "__main__":
    pos, tris = gear()
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "gear.glb")
    if sys.argv[1:2] == ["--out"]:
        out = sys.argv[2]
    with open(out, "wb") as f:
        f.write(glb([("gear", pos, tris)]))
    print(f"{out}: {len(tris)} triangles, {len(pos)} vertices")
