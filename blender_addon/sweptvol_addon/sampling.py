"""Adaptive sampling: follow Blender's motion between samples where the screw motion does not.

Plain Python and numpy (no bpy), tested by blender_addon/tests/test_sampling.py.

The daemon covers, between two consecutive rows of a part, the screw motion from the one pose
to the next (docs/design.md, "Continuous motion"):

    M(s) = G0 · exp(s·ξ) · ((1 - s)·S0 + s·S1),   s in [0, 1],   M = G·S (polar), exp(ξ) = G0⁻¹G1.

Blender moves an object by its own F-curves (Bezier easing, overshoot), constraints and parents,
which need not be that screw. This module measures the difference where it matters: at the
probe sub-frames f0 + q·(f1 - f0), q in PROBES, of every interval, it compares Blender's world
matrix at that sub-frame with the screw's at s = q, as the largest distance over the object's
vertices (the difference is affine, so its norm is convex and no point of the object strays
farther than its vertices). An interval whose deviation exceeds the threshold, or that turns
by MAX_TURN_DEGREES or more, is halved, down to `max_halvings` halvings of the sampling step;
the probes of the halves are measured in turn. What remains is recorded: the largest deviation
measured at any probe of the final intervals, and every interval still above the threshold at
the limit.

What this does and does not guarantee: the daemon's sweep covers the screw motion between the
final rows, with its stated bound and clearance. At every probe sub-frame Blender's placement
of every point of the object is within the recorded deviation of the screw's; a deviation below
the result's clearance puts those placements inside the result. Between probes, Blender's
curves are not evaluated: a wiggle narrower than the probe spacing can go unseen.

Matrices are 4x4 numpy arrays acting on column vectors (Blender's `matrix_world` as an array).
The screw does not depend on the world frame: for a rotation C, the screw between C·M0·Cᵀ and
C·M1·Cᵀ is C·M(s)·Cᵀ, so Blender's space (Z up) and the daemon's glTF space (Y up) agree.
"""

import math

import numpy as np

PROBES = (0.25, 0.5, 0.75)  # where each interval is checked, as fractions of it
MAX_TURN_DEGREES = 175.0  # an interval turning more is halved: the daemon refuses 179.9° and up
DEFAULT_HALVINGS = 6  # the finest interval is step / 2^6
# The daemon's default radii (`--radii exact`, src/input/grid.rs): ε = 0.6h and the clearance
# c = δ - √3h/2 - ε = 0.07h. The result's clearance is c less the output rounding (at most 0.01
# voxels); a deviation below it keeps a probe inside.
CLEARANCE_VOXELS = 0.06
# What a tolerance is divided by for the voxel size, in voxels: the stated bound with a
# face-joined voxel, √11/2 + δ/h, plus 0.1 for rounding (Radii::k_tolerance), plus μ = 1/4.
BOUND_VOXELS = math.sqrt(11.0) / 2.0 + 0.6 + math.sqrt(3.0) / 2.0 + 0.07 + 0.1 + 0.25
EPS = np.finfo(float).eps


# ---------------------------------------------------------------------------------------------
# The screw motion (the daemon's model, src/input/motion.rs, written again)


def polar_split(m):
    """M = G·S: (R, t, S) with R a rotation (det +1), t the translation, S symmetric (det S < 0
    for a mirrored object). Higham's iteration, as the daemon. Raises ValueError if singular."""
    a = np.asarray(m, dtype=float)[:3, :3]
    det = float(np.linalg.det(a))
    if not math.isfinite(det) or det == 0.0:
        raise ValueError("the object's world matrix is singular (a zero scale?)")
    x = a.copy()
    for _ in range(100):
        nxt = 0.5 * (x + np.linalg.inv(x).T)
        change = float(np.abs(nxt - x).max())
        x = nxt
        if change <= 4.0 * EPS:
            break
    r, s = (-x, -(x.T @ a)) if det < 0.0 else (x, x.T @ a)
    return r, np.asarray(m, dtype=float)[:3, 3].copy(), 0.5 * (s + s.T)


def rotation_vector(r):
    """The rotation vector ω (axis times angle, |ω| <= π) of a rotation matrix, by way of its
    unit quaternion (stable at every angle)."""
    tr = np.trace(r)
    if tr > max(r[0, 0], r[1, 1], r[2, 2]):
        w = 0.5 * math.sqrt(max(1.0 + tr, 0.0))
        v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / (4.0 * w)
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        vi = 0.5 * math.sqrt(max(1.0 + r[i, i] - r[j, j] - r[k, k], 0.0))
        v = np.zeros(3)
        v[i] = vi
        v[j] = (r[j, i] + r[i, j]) / (4.0 * vi)
        v[k] = (r[k, i] + r[i, k]) / (4.0 * vi)
        w = (r[k, j] - r[j, k]) / (4.0 * vi)
    if w < 0.0:
        w, v = -w, -v
    norm = float(np.linalg.norm(v))
    if norm == 0.0:
        return np.zeros(3)
    return v / norm * (2.0 * math.atan2(norm, w))


def _cross(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _rotation(w):
    """exp([ω]×): Rodrigues' formula, with its series near 0."""
    th2 = float(w @ w)
    th = math.sqrt(th2)
    a, b = (1.0 - th2 / 6.0, 0.5 - th2 / 24.0) if th < 1e-4 else (math.sin(th) / th,
                                                                    (1.0 - math.cos(th)) / th2)
    k = _cross(w)
    return np.eye(3) + a * k + b * (k @ k)


def _v_matrix(w):
    """V(ω) = I + (1-cos θ)/θ²·[ω]× + (θ-sin θ)/θ³·[ω]×²: a twist's v to its translation."""
    th2 = float(w @ w)
    th = math.sqrt(th2)
    if th < 1e-4:
        b, c = 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0
    else:
        b, c = (1.0 - math.cos(th)) / th2, (th - math.sin(th)) / (th2 * th)
    k = _cross(w)
    return np.eye(3) + b * k + c * (k @ k)


class Screw:
    """The motion from pose m0 (s = 0) to pose m1 (s = 1) that the daemon sweeps."""

    def __init__(self, m0, m1):
        self.r0, self.t0, self.s0 = polar_split(m0)
        r1, t1, self.s1 = polar_split(m1)
        self.omega = rotation_vector(self.r0.T @ r1)
        self.turn_degrees = math.degrees(float(np.linalg.norm(self.omega)))
        self.v = np.linalg.solve(_v_matrix(self.omega), self.r0.T @ (t1 - self.t0))

    def at(self, s):
        w = self.omega * s
        out = np.eye(4)
        out[:3, :3] = self.r0 @ _rotation(w) @ (self.s0 * (1.0 - s) + self.s1 * s)
        out[:3, 3] = self.t0 + self.r0 @ (_v_matrix(w) @ (self.v * s))
        return out


def deviation(a, b, vertices):
    """Largest distance between a·p and b·p over the rows p of `vertices` (local, (n, 3))."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    if len(vertices) == 0:
        return 0.0
    off = vertices @ d[:3, :3].T + d[:3, 3]
    return float(np.sqrt((off * off).sum(axis=1).max()))


# ---------------------------------------------------------------------------------------------
# Thresholds


def threshold_for_tolerance(tolerance):
    """The deviation allowed at a probe for a job with this tolerance (the stated bound): a
    quarter of it, and at most the result's clearance (the voxel size is tolerance/BOUND)."""
    return min(0.25 * tolerance, CLEARANCE_VOXELS * tolerance / BOUND_VOXELS)


def threshold_for_resolution(extent, resolution):
    """The same for a job with a resolution: the voxel size is at least extent/resolution (the
    daemon's grid spans at least the box of the sampled poses, whose longest edge is `extent`),
    so that voxel size, used in place of the real one, makes the threshold smaller, never larger."""
    h = extent / resolution
    return min(0.25 * BOUND_VOXELS * h, CLEARANCE_VOXELS * h)


def posed_extent(placements, vertices, limit=4096):
    """Longest edge of the box of the posed vertices over the given placements, measured on at
    most `limit` vertices per object (a subset: the box can only shrink, which keeps the
    resolution threshold on the safe side)."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for by_name in placements.values():
        for name, m in by_name.items():
            v = vertices[name]
            v = v[:: max(1, len(v) // limit)]
            if len(v) == 0:
                continue
            p = v @ np.asarray(m)[:3, :3].T + np.asarray(m)[:3, 3]
            lo, hi = np.minimum(lo, p.min(axis=0)), np.maximum(hi, p.max(axis=0))
    return float((hi - lo).max()) if np.isfinite(lo).all() else 0.0


# ---------------------------------------------------------------------------------------------
# The refinement


def _key(frame):
    return round(float(frame), 9)


class Record:
    """What the refinement did to one object."""

    def __init__(self, name):
        self.name = name
        self.frames = []  # the object's rows, in order
        self.worst = 0.0  # the largest deviation measured at a probe of a final interval
        self.worst_at = None  # (f0, f1) of that interval
        self.halved = 0  # intervals split
        self.probes = 0  # probe sub-frames measured
        self.unresolved = []  # (f0, f1, deviation) still above the threshold at the limit

    def as_dict(self):
        return {"object": self.name, "rows": len(self.frames), "halved": self.halved,
                "probes": self.probes, "worst": self.worst,
                "worst_between": list(self.worst_at) if self.worst_at else None,
                "unresolved": [list(u) for u in self.unresolved]}


def refine(frames, placements, evaluate, vertices, threshold, max_halvings):
    """Halve the intervals of each object where Blender's motion strays from the screw.

    frames: the sampled frames, increasing (every object is sampled at each).
    placements: {frame: {object name: 4x4 world matrix}} for every sampled frame; extended in
        place with every frame evaluated here.
    evaluate(frames): {frame: {object name: 4x4}} for a list of new frames (called once per
        round of halving, so that Blender sets each frame once).
    vertices: {object name: (n, 3) local vertex positions}.
    Returns {object name: Record}; each record's frames are keys of `placements`.
    """
    if not threshold > 0.0:
        raise ValueError("the deviation threshold must be positive")
    placed = {_key(f): by_name for f, by_name in placements.items()}
    names = list(vertices)
    records = {n: Record(n) for n in names}
    # One entry per interval still to decide: (name, f0, f1, halvings so far).
    pending = [(n, a, b, 0) for n in names for a, b in zip(frames, frames[1:], strict=False)]
    final = {n: set(_key(f) for f in frames) for n in names}
    raw = {_key(f): f for f in placements}  # the frame value each placement was evaluated at
    while pending:
        wanted, seen = [], set()
        for _, a, b, _ in pending:
            for q in PROBES:
                f = a + q * (b - a)
                if _key(f) not in placed and _key(f) not in seen:
                    seen.add(_key(f))
                    wanted.append(f)
        if wanted:
            fresh = evaluate(wanted)
            for f in wanted:
                placed[_key(f)] = fresh[f]
                placements[f] = fresh[f]
                raw[_key(f)] = f
        following = []
        for name, a, b, level in pending:
            rec = records[name]
            screw = Screw(placed[_key(a)][name], placed[_key(b)][name])
            worst = 0.0
            for q in PROBES:
                f = a + q * (b - a)
                worst = max(worst, deviation(screw.at(q), placed[_key(f)][name], vertices[name]))
                rec.probes += 1
            too_far = worst > threshold or screw.turn_degrees >= MAX_TURN_DEGREES
            if too_far and level < max_halvings:
                mid = a + 0.5 * (b - a)
                final[name].add(_key(mid))  # a probe of this interval: evaluated already
                rec.halved += 1
                following += [(name, a, mid, level + 1), (name, mid, b, level + 1)]
                continue
            if worst > rec.worst:
                rec.worst, rec.worst_at = worst, (a, b)
            if too_far:
                rec.unresolved.append((a, b, worst))
        pending = following
    for name in names:
        rec = records[name]
        rec.frames = sorted((raw[k] for k in final[name]), key=float)
        rec.unresolved.sort()
    return records


def summary(records, threshold, step, max_halvings):
    """The record written beside the job's inputs (exchange.SAMPLING) and shown on the result."""
    recs = list(records.values())
    worst = max(recs, key=lambda r: r.worst) if recs else None
    return {
        "threshold": threshold,
        "probes_per_interval": len(PROBES),
        "max_halvings": max_halvings,
        "finest_step": step / 2 ** max_halvings,
        "worst_deviation": worst.worst if worst else 0.0,
        "worst_object": worst.name if worst else None,
        "worst_between": list(worst.worst_at) if worst and worst.worst_at else None,
        "rows_added": sum(r.halved for r in recs),
        "probes": sum(r.probes for r in recs),
        "unresolved": sum(len(r.unresolved) for r in recs),
        "objects": [r.as_dict() for r in recs],
    }
