"""Tests of the add-on's adaptive sampling (no Blender): the screw motion, the deviation, and the
halving of intervals where a motion strays from the screw.

Run: target/test-venv/bin/python -m pytest blender_addon/tests/test_sampling.py
"""

import math
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "sweptvol_addon"))
import sampling as sm  # noqa: E402  (the module itself: the package __init__ needs bpy)

RNG = np.random.default_rng(16)


def axis_angle(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def pose(r=None, t=(0, 0, 0), s=None):
    m = np.eye(4)
    m[:3, :3] = (np.eye(3) if r is None else r) @ (np.eye(3) if s is None else s)
    m[:3, 3] = t
    return m


def random_rotation():
    return axis_angle(RNG.normal(size=3), RNG.uniform(0, math.pi * 0.95))


def helix(c, axis, angle, pitch, s):
    """The screw about the line through c along the unit `axis`: turn s·angle, advance s·pitch
    (an independent form: the axis-point construction, not the twist's exponential)."""
    m = np.eye(4)
    r = axis_angle(axis, s * angle)
    m[:3, :3] = r
    m[:3, 3] = c - r @ c + s * pitch * np.asarray(axis, dtype=float)
    return m


def test_screw_meets_both_poses_and_is_the_helix():
    for _ in range(50):
        axis = RNG.normal(size=3)
        axis /= np.linalg.norm(axis)
        c, angle, pitch = RNG.normal(size=3) * 5, RNG.uniform(-3.0, 3.0), RNG.normal() * 2
        m0 = pose(random_rotation(), RNG.normal(size=3) * 10)
        screw = sm.Screw(m0, helix(c, axis, angle, pitch, 1.0) @ m0)
        for s in (0.0, 0.3, 0.5, 1.0):
            assert np.allclose(screw.at(s), helix(c, axis, angle, pitch, s) @ m0, atol=1e-9)
        assert screw.turn_degrees == pytest.approx(math.degrees(abs(angle)), abs=1e-7)


def test_screw_with_stretch_goes_linearly_and_keeps_a_mirror():
    s0, s1 = np.diag([1.0, 2.0, 0.5]), np.diag([3.0, 1.0, 0.5])
    r0, r1 = axis_angle((0, 0, 1), 0.2), axis_angle((0, 0, 1), 1.2)
    screw = sm.Screw(pose(r0, (1, 2, 3), s0), pose(r1, (4, 5, 6), s1))
    half = screw.at(0.5)
    assert np.allclose(half[:3, :3], axis_angle((0, 0, 1), 0.7) @ (0.5 * (s0 + s1)), atol=1e-12)
    mirror = np.diag([-1.0, 1.0, 1.0])
    m = sm.Screw(pose(r0, (0, 0, 0), mirror), pose(r1, (0, 0, 0), mirror))
    assert np.linalg.det(m.at(0.5)[:3, :3]) == pytest.approx(-1.0)
    assert m.turn_degrees == pytest.approx(math.degrees(1.0))
    with pytest.raises(ValueError, match="singular"):
        sm.Screw(pose(s=np.diag([1.0, 0.0, 1.0])), pose())


def test_rotation_vector_at_every_angle():
    for angle in (0.0, 1e-9, 1e-3, 1.0, 3.0, math.pi - 1e-6):
        axis = RNG.normal(size=3)
        axis /= np.linalg.norm(axis)
        w = sm.rotation_vector(axis_angle(axis, angle))
        assert np.linalg.norm(w) == pytest.approx(angle, abs=1e-7)
        if angle > 1e-6:
            assert np.allclose(w / np.linalg.norm(w), axis, atol=1e-6)


def test_deviation_is_the_farthest_vertex():
    verts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0]])
    a = pose(t=(0.5, 0, 0))
    b = pose(axis_angle((0, 0, 1), math.pi / 2))
    want = max(np.linalg.norm((a @ np.append(p, 1))[:3] - (b @ np.append(p, 1))[:3]) for p in verts)
    assert sm.deviation(a, b, verts) == pytest.approx(want)


def test_thresholds_stay_below_the_clearance():
    t = 0.05
    h = t / sm.BOUND_VOXELS
    # the exact radii's clearance 0.07h less the output rounding's 0.01h
    assert sm.threshold_for_tolerance(t) <= 0.25 * t
    assert sm.threshold_for_tolerance(t) <= 0.06 * h
    # extent/resolution underestimates the daemon's voxel: the threshold only shrinks
    assert sm.threshold_for_resolution(2.0, 100) <= 0.06 * 0.02


def run_refine(motion, frames, threshold, halvings, vertices):
    """Refine `frames` for one object moving by motion(frame) -> 4x4; count evaluations."""
    calls = []

    def evaluate(fs):
        calls.append(list(fs))
        return {f: {"obj": motion(f)} for f in fs}

    placements = {f: {"obj": motion(f)} for f in frames}
    rec = sm.refine(frames, placements, evaluate, {"obj": vertices}, threshold, halvings)["obj"]
    assert set(rec.frames) <= set(placements)  # every row has its evaluated placement
    return rec, calls


CUBE = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])


def test_a_motion_that_is_the_screw_adds_nothing():
    frames = [1.0, 2.0, 3.0, 4.0]
    rec, calls = run_refine(lambda f: helix(np.array([2.0, 0, 0]), np.array([0, 0, 1.0]),
                                            math.radians(90 * f), 0.3 * f, 1.0), frames, 1e-6, 6, CUBE)
    assert rec.frames == frames and rec.halved == 0 and rec.worst < 1e-9
    assert len(calls) == 1 and len(calls[0]) == 3 * 3  # three probes per interval, one round


def bulge(f):
    """A translation along x whose y bulges by sin(π·f)·0.8 between whole frames (an F-curve
    that overshoots between its samples), and a turn that follows the screw."""
    return pose(axis_angle((0, 0, 1), 0.1 * f), (f, 0.8 * math.sin(math.pi * f) ** 2, 0.0))


def test_a_bulging_motion_is_halved_until_it_is_followed():
    frames = [0.0, 1.0, 2.0]
    threshold = 0.01
    rec, calls = run_refine(bulge, frames, threshold, 8, CUBE)
    assert rec.halved > 0 and len(rec.frames) > len(frames)
    assert rec.worst <= threshold and not rec.unresolved
    assert rec.frames == sorted(rec.frames) and set(frames) <= set(rec.frames)
    # between the final rows, at 41 points each (not only the probes), the motion stays near
    # the screw the daemon sweeps
    for a, b in zip(rec.frames, rec.frames[1:], strict=False):
        screw = sm.Screw(bulge(a), bulge(b))
        for q in np.linspace(0, 1, 41):
            dev = sm.deviation(screw.at(q), bulge(a + q * (b - a)), CUBE)
            # between probes the screw's error is a smooth function's: bounded by a small
            # multiple of the probed one for this motion
            assert dev <= 2.0 * threshold, (a, b, q, dev)
    # each round evaluates each new frame once
    flat = [f for c in calls for f in c]
    assert len(flat) == len(set(round(f, 9) for f in flat))


def test_the_limit_is_stated_when_it_is_reached():
    rec, _ = run_refine(bulge, [0.0, 1.0], 1e-7, 2, CUBE)
    assert len(rec.frames) == 5  # two halvings: quarters
    assert rec.unresolved and all(dev > 1e-7 for _, _, dev in rec.unresolved)
    assert rec.worst == max(dev for _, _, dev in rec.unresolved)
    off, _ = run_refine(bulge, [0.0, 1.0], 1e-7, 0, CUBE)  # 0 halvings: measure only
    assert off.frames == [0.0, 1.0] and off.worst > 0.1


def test_a_turn_near_half_a_revolution_is_halved():
    rec, _ = run_refine(lambda f: pose(axis_angle((0, 0, 1), math.radians(178.0 * f))),
                        [0.0, 1.0], 10.0, 6, CUBE)
    assert rec.frames == [0.0, 0.5, 1.0]


def test_objects_are_refined_each_on_its_own():
    frames = [0.0, 1.0, 2.0]

    def evaluate(fs):
        return {f: {"still": pose(t=(f, 0, 0)), "bulge": bulge(f)} for f in fs}

    placements = evaluate(frames)
    recs = sm.refine(frames, placements, evaluate, {"still": CUBE, "bulge": CUBE}, 0.01, 6)
    assert recs["still"].frames == frames and recs["still"].halved == 0
    assert len(recs["bulge"].frames) > 3
    info = sm.summary(recs, 0.01, 1.0, 6)
    assert info["worst_object"] == "bulge" and info["rows_added"] == recs["bulge"].halved
    assert info["finest_step"] == 1.0 / 64 and info["unresolved"] == 0


def test_posed_extent_never_exceeds_the_true_box():
    verts = RNG.normal(size=(20000, 3))
    placements = {f: {"o": pose(random_rotation(), RNG.normal(size=3))} for f in range(5)}
    full = sm.posed_extent(placements, {"o": verts}, limit=10 ** 9)
    part = sm.posed_extent(placements, {"o": verts}, limit=100)
    assert 0 < part <= full


def test_the_thresholds_constants_are_the_daemons(sweptvol_bin, tmp_path):
    """The voxel size and clearance the add-on assumes for a tolerance are those the daemon
    reports: if sweptvol's default δ, ε or μ change, this fails until sampling.py follows."""
    import json
    import subprocess

    import trimesh  # in the test venv (scripts/test-all.sh): a missing one fails, never skips
    trimesh.creation.box(extents=(1.0, 0.5, 0.3)).export(tmp_path / "box.glb")
    (tmp_path / "box.csv").write_text("tx,ty,tz,qw,qx,qy,qz\n0,0,0,1,0,0,0\n0.5,0,0,1,0,0,0\n")
    tolerance = 0.05
    proc = subprocess.run(
        [sweptvol_bin, "run", "--generator", str(tmp_path / "box.glb"), "--trajectory",
         str(tmp_path / "box.csv"), "--out", str(tmp_path / "out"), "--tolerance", str(tolerance),
         "--backend", "cpu", "--quiet"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "out" / "box.report.json").read_text())
    h = report["parameters"]["voxel_size"]
    assert report["motion"]["model"] == "screw"
    assert h == pytest.approx(tolerance / sm.BOUND_VOXELS, rel=1e-9)
    assert report["mesh"]["clearance"] >= sm.CLEARANCE_VOXELS * h
    assert report["mesh"]["clearance"] < (sm.CLEARANCE_VOXELS + 0.05) * h  # not far off either
    assert sm.threshold_for_tolerance(tolerance) <= report["mesh"]["clearance"]
