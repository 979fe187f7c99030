"""Write examples/bunny-fine-vibration.csv: 1,000 rows of a finely sampled vibration of the bunny.

A smooth vibration (three sine components per axis, 0.05 units and 0.3 degrees peak) sampled at
40 rows per period of its fastest component, so that no point of the bunny (about 10 units
across) moves more than about 0.015 units between rows: under half a voxel at resolution 256,
the sub-voxel case of docs/benchmarks.md ("Continuous motion"). Deterministic: no random numbers.

    python3 examples/make_fine_vibration.py > examples/bunny-fine-vibration.csv
"""

import math

ROWS = 1000
PERIOD = 40.0  # rows per period of the fastest component
AMPLITUDE = 0.05  # translation, units
TURN = math.radians(0.3)  # rotation, radians


def wave(t, phase):
    w = 2.0 * math.pi / PERIOD
    return (math.sin(w * t + phase) + 0.5 * math.sin(0.37 * w * t + 2 * phase)
            + 0.25 * math.sin(0.11 * w * t + 3 * phase)) / 1.75


print("# examples/bunny-fine-vibration.csv: 1,000 rows of a finely sampled vibration of the bunny")
print("# (examples/make_fine_vibration.py). Pose form: translation then unit quaternion, glTF world frame.")
print("frame,tx,ty,tz,qw,qx,qy,qz")
for k in range(ROWS):
    t = [AMPLITUDE * wave(k, p) for p in (0.0, 1.1, 2.3)]
    r = [TURN * wave(k, p) for p in (0.7, 1.9, 2.9)]
    angle = math.sqrt(sum(x * x for x in r))
    s = math.sin(angle / 2) / angle if angle > 0 else 0.5
    q = [math.cos(angle / 2)] + [x * s for x in r]
    print(f"{k},{t[0]:.6f},{t[1]:.6f},{t[2]:.6f},{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},{q[3]:.9f}")
