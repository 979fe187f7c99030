"""End-to-end test of the add-on in real Blender, with a real `sweptvol watch` daemon.

Run by blender_addon/tests/run-e2e.sh, in Blender itself or in PyPI's `bpy` module:
    BLENDER_USER_SCRIPTS=<tmp> blender -b --factory-startup --python-exit-code 1 \
        --python blender_addon/tests/blender_e2e.py -- --zip target/sweptvol_addon.zip \
        --binary target/release/sweptvol --work <tmp> [--mode legacy|extension]
    BLENDER_USER_SCRIPTS=... BLENDER_USER_EXTENSIONS=... python blender_e2e.py --zip ... (bpy)

Installs the add-on zip into the (fresh) profile, the legacy way (preferences.addon_install +
addon_enable, module `sweptvol_addon`) or as an extension (extensions.package_install_files, module
`bl_ext.user_default.sweptvol_addon`; 4.2+), builds a scene with two animated
objects (one parented, with keyed translation and rotation and a scale that is not 1, one with a
rigid modifier and a constraint), presses `sweptvol.compute` (the add-on starts the daemon
itself), and checks in Blender's world coordinates, at every sampled frame:
  1. every vertex (and face centre) of every posed object is inside the imported mesh
     (generalized winding number >= 0.5);
  2. every vertex of the imported mesh is within the reported bound of the posed objects;
  3. Blender's non-manifold selection (edit mode, select_non_manifold) on the imported mesh is
     empty, and so is bmesh's count of non-manifold edges and vertices.
Continuous motion: a rod turning 90° per frame, sampled every frame, is inside the result at
every 0.05 frame (and the discrete result fails that check); a block whose BACK-eased F-curve
overshoots between two samples has its interval halved until the add-on follows it, is inside
the result at every 0.01 frame, and with Halvings 0 is not (and the warning names it).
Also: a deforming object is refused with its name and cause, the depth images load readable,
a daemon error comes back as a Blender report, cancelling works, disabling the add-on stops the
daemon it started, and with auto_start off the job is still submitted and the user told.
An import failure shows its own error (not the daemon's status message), and no deprecation
warning comes from the add-on's code.

Ends with `e2e: PASS` or `e2e: FAIL ...`, flushed, then os._exit: the bpy module can crash (4.2,
after a glTF export) or hang (4.5) at interpreter exit, so nothing may run after the verdict.
"""

import argparse
import importlib
import json
import math
import os
import shutil
import sys
import time
import traceback
import warnings

import bpy
import numpy as np

# Blender passes the script's arguments after "--"; the bpy module sees plain sys.argv.
argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
ap = argparse.ArgumentParser()
ap.add_argument("--zip", required=True)
ap.add_argument("--binary", required=True)
ap.add_argument("--work", required=True)
ap.add_argument("--resolution", type=int, default=64)
ap.add_argument("--mode", choices=("legacy", "extension"), default="legacy")
args = ap.parse_args(argv)

FRAMES = (1.0, 9.0, 0.5)  # start, end, step: sub-frames included


def log(*a):
    print("e2e:", *a, flush=True)


def check(cond, message):
    if not cond:
        raise AssertionError(message)


# Checks whose failure is reported at the end (after every other check has run), so that one
# known problem does not hide the others.
DEFERRED = []


def deferred_check(cond, message):
    if not cond:
        log("FAILED (reported at the end):", message)
        DEFERRED.append(message)


# ---------------------------------------------------------------------------------------------
# Installing the add-on, both ways


def install_addon():
    """Install args.zip into the fresh profile and enable it; returns the module name."""
    zip_path = os.path.abspath(args.zip)
    if args.mode == "legacy":
        root = os.environ.get("BLENDER_USER_SCRIPTS", "")
        check(root and os.path.isdir(root), "run with BLENDER_USER_SCRIPTS=<empty tmp dir>")
        check(bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True) == {"FINISHED"},
              "addon_install failed")
        module = "sweptvol_addon"
        check(bpy.ops.preferences.addon_enable(module=module) == {"FINISHED"}, "addon_enable failed")
    else:
        root = os.environ.get("BLENDER_USER_EXTENSIONS", "")
        check(root and os.path.isdir(root), "run with BLENDER_USER_EXTENSIONS=<empty tmp dir>")
        check(hasattr(bpy.ops, "extensions") and "package_install_files" in dir(bpy.ops.extensions),
              f"Blender {bpy.app.version_string} has no extensions (4.2+ only)")
        check(bpy.ops.extensions.package_install_files(
            filepath=zip_path, repo="user_default", enable_on_install=True) == {"FINISHED"},
            "package_install_files failed")
        names = [a.module for a in bpy.context.preferences.addons
                 if a.module.rsplit(".", 1)[-1] == "sweptvol_addon"]
        check(len(names) == 1, f"expected one enabled sweptvol add-on, got {names}")
        module = names[0]
        check(module.startswith("bl_ext.") and module != "sweptvol_addon",
              f"an extension's module should be bl_ext.<repo>.sweptvol_addon, got {module}")
    mod = importlib.import_module(module)
    check(os.path.abspath(mod.__file__).startswith(os.path.realpath(root))
          or os.path.realpath(mod.__file__).startswith(os.path.realpath(root)),
          f"the add-on was not installed from the zip into {root}: {mod.__file__}")
    return module


def configure(module, jobs, auto_start):
    """Set the add-on's preferences, looked up by the module it was enabled as."""
    prefs = bpy.context.preferences.addons[module].preferences
    prefs.watch_folder = jobs
    prefs.sweptvol_binary = os.path.abspath(args.binary)
    prefs.auto_start = auto_start
    prefs.backend = "cpu"
    check(prefs.watch_folder == jobs and prefs.auto_start == auto_start, "preferences not set")
    return prefs


def key(obj, frame, loc=None, rot=None):
    if loc is not None:
        obj.location = loc
        obj.keyframe_insert("location", frame=frame)
    if rot is not None:
        obj.rotation_euler = [math.radians(a) for a in rot]
        obj.keyframe_insert("rotation_euler", frame=frame)

def select(objs):
    for o in bpy.context.view_layer.objects:
        o.select_set(o in objs)
    bpy.context.view_layer.objects.active = objs[0]

def world_mesh(obj):
    """(vertices (n,3), triangles (m,3,3)) of an object's evaluated mesh in world space now."""
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    me.calc_loop_triangles()
    co = np.empty(len(me.vertices) * 3)
    me.vertices.foreach_get("co", co)
    tri = np.empty(len(me.loop_triangles) * 3, dtype=np.int64)
    me.loop_triangles.foreach_get("vertices", tri)
    m = np.array(ev.matrix_world)
    ev.to_mesh_clear()
    co = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    return co, co[tri.reshape(-1, 3)]


def winding_numbers(points, tris):
    """Generalized winding number of a closed triangle mesh at each point (Van Oosterom and
    Strackee solid angles): about 1 inside, 0 outside."""
    out = np.zeros(len(points))
    for s in range(0, len(points), 256):
        p = points[s:s + 256, None, :]
        a, b, c = tris[None, :, 0] - p, tris[None, :, 1] - p, tris[None, :, 2] - p
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        det = np.einsum("ijk,ijk->ij", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ijk,ijk->ij", a, b) * lc
               + np.einsum("ijk,ijk->ij", b, c) * la + np.einsum("ijk,ijk->ij", c, a) * lb)
        out[s:s + 256] = 2.0 * np.arctan2(det, den).sum(axis=1) / (4.0 * math.pi)
    return out


def point_triangle_distance(points, tris):
    """Distance from each point to the nearest triangle (exact, Ericson's regions)."""
    best = np.full(len(points), np.inf)
    a0, b0, c0 = tris[:, 0], tris[:, 1], tris[:, 2]
    for s in range(0, len(points), 128):
        p = points[s:s + 128, None, :]
        a, b, c = a0[None], b0[None], c0[None]
        ab, ac, ap_ = b - a, c - a, p - a
        dot = lambda x, y: np.einsum("ijk,ijk->ij", x, y)  # noqa: E731
        d1, d2 = dot(ab, ap_), dot(ac, ap_)
        bp = p - b
        d3, d4 = dot(ab, bp), dot(ac, bp)
        cp = p - c
        d5, d6 = dot(ab, cp), dot(ac, cp)
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        denom = va + vb + vc
        with np.errstate(divide="ignore", invalid="ignore"):
            v = vb / denom
            w = vc / denom
            q = a + ab * v[..., None] + ac * w[..., None]  # interior
            t_ab = d1 / (d1 - d3)
            t_ac = d2 / (d2 - d6)
            t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        cases = [
            ((d1 <= 0) & (d2 <= 0), a + 0 * ab),
            ((d3 >= 0) & (d4 <= d3), b + 0 * ab),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab[..., None]),
            ((d6 >= 0) & (d5 <= d6), c + 0 * ab),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac[..., None]),
            ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + (c - b) * t_bc[..., None]),
        ]
        for cond, point in reversed(cases):  # Ericson's order: the first matching case wins
            q = np.where(cond[..., None], point, q)
        dist = np.linalg.norm(p - q, axis=2)
        best[s:s + 128] = np.minimum(best[s:s + 128], np.nan_to_num(dist, nan=np.inf).min(axis=1))
    return best


def non_manifold_check(obj):
    """Blender's own non-manifold selection (edit mode) and bmesh's counts on `obj`'s mesh:
    every edge with exactly two faces of consistent winding, every vertex a single fan."""
    import bmesh

    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bad_edges = [e for e in bm.edges if not e.is_manifold]
    by_faces = {}
    for e in bad_edges:
        by_faces.setdefault(len(e.link_faces), []).append(e)
    bad_verts = [v for v in bm.verts if not v.is_manifold]
    m = np.array(obj.matrix_world)
    where = [(m[:3, :3] @ np.array(v.co, dtype=float) + m[:3, 3]).round(4).tolist() for v in bad_verts[:5]]
    bm.free()

    view_layer = bpy.context.view_layer
    old_sel, old_active = [o for o in view_layer.objects if o.select_get()], view_layer.objects.active
    for o in view_layer.objects:
        o.select_set(o == obj)
    view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        bpy.ops.mesh.select_mode(type="VERT")
        bpy.ops.mesh.select_all(action="DESELECT")
        bpy.ops.mesh.select_non_manifold()
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
        for o in view_layer.objects:
            o.select_set(o in old_sel)
        view_layer.objects.active = old_active
    selected = sum(1 for v in obj.data.vertices if v.select)
    edges_sel = sum(1 for e in obj.data.edges if e.select)
    log(f"non-manifold check on '{obj.name}' ({len(obj.data.vertices)} vertices, "
        f"{len(obj.data.edges)} edges): select_non_manifold selects {selected} vertices and "
        f"{edges_sel} edges; bmesh: {len(bad_edges)} non-manifold edges "
        f"({', '.join(f'{len(v)} with {k} faces' for k, v in sorted(by_faces.items())) or 'none'}), "
        f"{len(bad_verts)} non-manifold vertices" + (f", e.g. at {where}" if where else ""))
    deferred_check(selected == 0 and not bad_edges and not bad_verts,
                   f"the imported mesh is not manifold: select_non_manifold selected {selected} "
                   f"vertices / {edges_sel} edges, bmesh found {len(bad_edges)} non-manifold edges "
                   f"and {len(bad_verts)} non-manifold vertices (e.g. at {where})")


def set_interpolation(obj, kind):
    """Set every keyframe of `obj`'s action to the interpolation `kind` (easing: automatic).
    4.4+ keeps F-curves in the layered action's channel bag of the object's slot (5.0 drops
    Action.fcurves); older Blenders have them on the action."""
    anim = obj.animation_data
    action = anim.action
    if getattr(action, "layers", None):
        curves = [fc for layer in action.layers for strip in layer.strips
                  for bag in [strip.channelbag(anim.action_slot)] if bag is not None
                  for fc in bag.fcurves]
    else:
        curves = list(action.fcurves)
    check(curves, f"no F-curves found on {obj.name}")
    for fc in curves:
        for kp in fc.keyframe_points:
            kp.interpolation = kind
            kp.easing = "AUTO"
        fc.update()
    bpy.context.view_layer.update()


def enclosure(scene, obj, swept, frames):
    """(points checked, points outside, an outside point or None): `obj`'s vertices and face
    centres posed at each frame, against the imported mesh `swept` (winding number < 0.5)."""
    _, tris = world_mesh(swept)
    pts = []
    for f in frames:
        scene.frame_set(int(math.floor(f)), subframe=f - math.floor(f))
        verts, t = world_mesh(obj)
        pts += [verts, t.mean(axis=1)]
    scene.frame_set(1)
    pts = np.concatenate(pts)
    out = np.flatnonzero(winding_numbers(pts, tris) < 0.5)
    return len(pts), len(out), (pts[out[0]].round(4).tolist() if len(out) else None)


def sweep_one(obj, operators, coll):
    """Compute `obj`'s swept volume (the panel's settings) and return (imported object, job)."""
    select([obj])
    check(bpy.ops.sweptvol.compute(wait=True, timeout=300) == {"FINISHED"}, f"compute {obj.name}")
    job = operators.JOBS[-1]
    check(job["state"] == "done", f"{obj.name}: job state {job['state']}")
    swept = coll.objects.get(job["imported"])
    check(swept is not None, f"{obj.name}: no imported object '{job['imported']}'")
    return swept, job


def continuous_motion(scene, settings, operators, exchange, coll):
    """A part turning 90° per frame, sampled every frame: enclosed at every 0.05 frame with
    continuous motion, not with discrete. A part whose F-curve overshoots between two samples
    (BACK easing): the add-on halves the interval until it follows the curve, and the result
    encloses it at every 0.01 frame; with no halving the same check fails."""
    from mathutils import Matrix

    # A rod from 0.1 to 1.1 along x, turning about the world z axis, linearly: Blender's motion
    # is exactly the screw between samples, so nothing is halved.
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0, 0, 0))
    spinner = bpy.context.active_object
    spinner.name = "Spinner"
    spinner.data.transform(Matrix.Translation((0.6, 0.0, 0.0)) @ Matrix.Diagonal((1.0, 0.2, 0.2, 1.0)))
    for f, angle in ((1, 0), (2, 90), (3, 180)):
        key(spinner, f, loc=(0, 0, 0), rot=(0, 0, angle))
    set_interpolation(spinner, "LINEAR")
    # A block pushed 2 units along x between frames 1 and 2 with BACK easing: it overshoots to
    # about x = 2.2 between the samples and comes back.
    bpy.ops.mesh.primitive_cube_add(size=0.4, location=(0, 3, 0))
    block = bpy.context.active_object
    block.name = "Overshoot"
    key(block, 1, loc=(0, 3, 0))
    key(block, 2, loc=(2, 3, 0))
    set_interpolation(block, "BACK")

    settings.use_scene_range = False
    settings.accuracy, settings.resolution = "RESOLUTION", args.resolution
    fine = [1.0 + 0.05 * k for k in range(41)]
    settings.frame_start, settings.frame_end, settings.frame_step = 1.0, 3.0, 1.0
    settings.motion, settings.halvings = "screw", 6
    swept, job = sweep_one(spinner, operators, coll)
    n, out, where = enclosure(scene, spinner, swept, fine)
    log(f"continuous, 90°/frame: {n} points at {len(fine)} sub-frames, {out} outside; "
        f"{swept['sweptvol_poses']} poses rendered, sub-frames added "
        f"{swept.get('sweptvol_sampling_rows_added')}, deviation "
        f"{swept.get('sweptvol_sampling_deviation')}")
    check(out == 0, f"continuous motion: {out} of {n} points of the turning rod are outside the "
          f"result, e.g. {where}")
    check(swept["sweptvol_motion"] == "screw" and swept["sweptvol_poses"] > 3,
          f"the sub-poses were not swept: {dict(swept.items())}")
    check(swept["sweptvol_sampling_rows_added"] == 0
          and swept["sweptvol_sampling_deviation"] < 1e-4,
          "a linear turn is the screw: nothing should be halved "
          f"({swept['sweptvol_sampling_rows_added']} added, {swept['sweptvol_sampling_deviation']})")

    settings.motion = "discrete"
    swept, job = sweep_one(spinner, operators, coll)
    n, out, where = enclosure(scene, spinner, swept, fine)
    log(f"discrete, 90°/frame: {out} of {n} points outside (as expected), e.g. {where}")
    check(out > 0, "the discrete result encloses the motion between samples: the check above "
          "could not fail")
    check("sweptvol_sampling_deviation" not in swept.keys()
          and not os.path.exists(os.path.join(job["dir"], exchange.SAMPLING)),
          "discrete motion should not refine nor record a sampling")

    settings.frame_start, settings.frame_end, settings.frame_step = 1.0, 2.0, 1.0
    fine = [1.0 + 0.01 * k for k in range(101)]
    settings.motion, settings.halvings = "screw", 6
    swept, job = sweep_one(block, operators, coll)
    record = exchange.read_sampling(job["dir"])
    rows = [r for r in open(os.path.join(job["dir"], exchange.TRAJECTORY)) if r[:1].isdigit()]
    n, out, where = enclosure(scene, block, swept, fine)
    log(f"overshoot, halvings 6: {len(rows)} rows for 2 samples, deviation "
        f"{record['worst_deviation']:.3g} (threshold {record['threshold']:.3g}), "
        f"{out} of {n} points outside")
    check(len(rows) > 2 and record["rows_added"] == len(rows) - 2,
          f"the overshoot was not followed: {len(rows)} rows, record {record}")
    check(record["unresolved"] == 0 and record["worst_deviation"] <= record["threshold"],
          f"the refinement did not reach its threshold: {record}")
    check(swept["sweptvol_sampling_deviation"] == record["worst_deviation"],
          "the result does not carry the sampling deviation")
    check(out == 0, f"{out} of {n} points of the overshooting block are outside, e.g. {where}")

    settings.halvings = 0
    swept, job = sweep_one(block, operators, coll)
    record = exchange.read_sampling(job["dir"])
    n, out, where = enclosure(scene, block, swept, fine)
    warning = operators.unresolved_warning(record)
    log(f"overshoot, no halving: deviation {record['worst_deviation']:.3g}, {out} of {n} points "
        f"outside (as expected), warning: {warning}")
    check(out > 0, "without halving the overshoot should leave the result: the check above "
          "could not fail")
    check(record["unresolved"] == 1 and "'Overshoot'" in warning and "Halvings" in warning,
          f"the unfollowed overshoot is not stated: {record}, {warning!r}")
    check(swept["sweptvol_sampling_unresolved"] == 1, "the result does not carry the unresolved count")
    settings.halvings = 6
    for o in (spinner, block):
        bpy.data.objects.remove(o)


def articulated(scene, settings, operators, exchange, coll):
    """A two-bone armature, a bar parented to each bone, both bones turning (60° and 90°) between
    two sampled frames: the add-on exports the bones as nodes with rows in parent space, the
    refinement has nothing to halve (each bone turns about one axis, the screw in its parent's
    frame), and the result encloses both bars at every 0.02 frame; the discrete result does not."""
    from mathutils import Matrix

    data = bpy.data.armatures.new("RigData")
    rig = bpy.data.objects.new("Rig", data)
    scene.collection.objects.link(rig)
    select([rig])
    bpy.ops.object.mode_set(mode="EDIT")
    upper = data.edit_bones.new("Upper")
    upper.head, upper.tail = (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)
    fore = data.edit_bones.new("Fore")
    fore.head, fore.tail = (1.0, 0.0, 0.0), (1.8, 0.0, 0.0)
    fore.parent, fore.use_connect = upper, True
    bpy.ops.object.mode_set(mode="OBJECT")
    bars = []
    for bone, (start, length) in (("Upper", (0.0, 1.0)), ("Fore", (1.0, 0.8))):
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0, 0, 0))
        bar = bpy.context.active_object
        bar.name = f"{bone} bar"
        bar.data.transform(Matrix.Diagonal((length, 0.1, 0.1, 1.0)))
        bar.parent, bar.parent_type, bar.parent_bone = rig, "BONE", bone
        bpy.context.view_layer.update()
        bar.matrix_world = Matrix.Translation((start + length / 2, 0.0, 0.0))
        bars.append(bar)
    for name, angle in (("Upper", 60.0), ("Fore", 90.0)):
        pb = rig.pose.bones[name]
        pb.rotation_mode = "XYZ"
        for f, a in ((1, 0.0), (2, angle)):
            pb.rotation_euler = (0.0, 0.0, math.radians(a))  # about the bone's z: a swing in x-y
            pb.keyframe_insert("rotation_euler", frame=f)
    set_interpolation(rig, "LINEAR")
    scene.frame_set(2)
    centre = bars[1].matrix_world.translation
    check(abs(centre.z) < 1e-6 and centre.y > 0.5,
          f"the rig does not swing in the x-y plane: the fore bar's centre at {tuple(centre)}")
    scene.frame_set(1)

    settings.use_scene_range = False
    settings.frame_start, settings.frame_end, settings.frame_step = 1.0, 2.0, 1.0
    settings.motion, settings.halvings = "screw", 6
    fine = [1.0 + 0.02 * k for k in range(51)]
    select(bars)
    check(bpy.ops.sweptvol.compute(wait=True, timeout=300) == {"FINISHED"}, "compute the rig")
    job = operators.JOBS[-1]
    check(job["state"] == "done", f"rig: job state {job['state']}")
    swept = coll.objects.get(job["imported"])
    job_json = json.load(open(os.path.join(job["dir"], exchange.JOB_JSON)))
    rows = open(os.path.join(job["dir"], exchange.TRAJECTORY)).read()
    check(job_json.get("rows") == "local" and "Rig:Fore," in rows and "Fore bar," in rows,
          f"the rig was not sent as a hierarchy: {job_json}")
    record = exchange.read_sampling(job["dir"])
    check(record["rows_added"] == 0, f"a bone turning about one axis is the screw in its parent's "
          f"frame: nothing should be halved ({record['rows_added']} added)")
    for bar in bars:
        n, out, where = enclosure(scene, bar, swept, fine)
        check(out == 0, f"rig: {out} of {n} points of '{bar.name}' are outside the result, e.g. {where}")
    log(f"armature: both bars enclosed at {len(fine)} sub-frames, rows in parent space, "
        f"{swept['sweptvol_poses']} poses rendered")

    settings.motion = "discrete"
    select(bars)
    check(bpy.ops.sweptvol.compute(wait=True, timeout=300) == {"FINISHED"}, "compute the rig, discrete")
    swept = coll.objects.get(operators.JOBS[-1]["imported"])
    n, out, where = enclosure(scene, bars[1], swept, fine)
    check(out > 0, "the discrete result encloses the rig's motion: the check above could not fail")
    settings.motion = "screw"
    for o in bars + [rig]:
        bpy.data.objects.remove(o)


def clearance(scene, settings, operators, exchange, coll, part, bar, posed_tris):
    """Obstacles from a collection: the clearance map comes back as objects with the per-vertex
    lower end readable and shown by a material, a closest-point marker, and the verdict as
    properties; every lower end is at most the vertex's true distance from the posed objects
    (`posed_tris`, at every sampled frame). A block through the part is a certain contact, in
    the job's line. Relative to Bar, the result follows Bar."""
    # The frames of section 3 (`posed_tris` holds the objects at each): the swept volume holds
    # the objects at every one of them, so its true distance from a point is at most theirs.
    settings.use_scene_range = False
    settings.frame_start, settings.frame_end, settings.frame_step = FRAMES
    settings.accuracy, settings.resolution = "RESOLUTION", args.resolution
    settings.motion, settings.halvings = "screw", 6
    obstacles = bpy.data.collections.new("Obstacles")
    scene.collection.children.link(obstacles)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=16, y_subdivisions=16, size=6.0,
                                    location=(0, 0, -1.6))
    floor = bpy.context.active_object
    floor.name = "Floor"
    for c in list(floor.users_collection):
        c.objects.unlink(floor)
    obstacles.objects.link(floor)
    settings.obstacles = obstacles
    select([part, bar])
    check(bpy.ops.sweptvol.compute(wait=True, timeout=400) == {"FINISHED"}, "compute with obstacles")
    job = operators.JOBS[-1]
    maps = [o for o in coll.objects if o.name == "Floor clearance"]
    check(len(maps) == 1, f"no 'Floor clearance' object: {[o.name for o in coll.objects]}")
    m = maps[0]
    attr = m.data.attributes.get("clearance")
    check(attr is not None and attr.domain == "POINT" and len(attr.data) == len(m.data.vertices),
          "the clearance attribute is missing or not per vertex")
    values = np.empty(len(attr.data))
    attr.data.foreach_get("value", values)
    colours = m.data.color_attributes.get("clearance colour")
    check(colours is not None, "no 'clearance colour' attribute")
    rgba = np.empty(len(colours.data) * 4)
    colours.data.foreach_get("color", rgba)
    rgba = rgba.reshape(-1, 4)
    mat = m.data.materials[0]
    shows = any(n.bl_idname == "ShaderNodeAttribute" and n.attribute_name == "clearance colour"
                and n.outputs["Color"].is_linked for n in mat.node_tree.nodes)
    check(shows, "the clearance material does not show the colour attribute")
    verdict = m.get("sweptvol_verdict")
    check(verdict in ("clear", "possible-contact"), f"floor verdict {verdict}")
    lower = float(m["sweptvol_clearance_lower"])
    check(np.isfinite(values).all() and values.min() >= lower - 1e-6,
          f"lower ends {values.min()}..{values.max()}, the obstacle's {lower}")
    fv, _ = world_mesh(m)
    truth = point_triangle_distance(fv, posed_tris)
    check((values <= truth + 1e-4).all(),
          f"a lower end exceeds the true distance: {float((values - truth).max())}")
    check(rgba[:, :3].min() >= 0 and rgba[:, 3].min() == 1.0 and np.ptp(rgba[:, 1]) > 0,
          "the colours do not vary over the obstacle")
    check(bpy.data.objects.get("Floor closest point") is not None, "no closest-point marker")
    log(f"clearance map: Floor {verdict}, lower ends {values.min():.4g}..{values.max():.4g} "
        f"(true {truth.min():.4g}..), interval [{lower:.4g}, {m['sweptvol_clearance_upper']:.4g}]")

    # A block through the part at frame 1: a certain contact, said in the job's line.
    bpy.ops.mesh.primitive_cube_add(size=0.3, location=(0.4, 0, 0))
    pin = bpy.context.active_object
    pin.name = "Pin"
    for c in list(pin.users_collection):
        c.objects.unlink(pin)
    obstacles.objects.link(pin)
    select([part])
    check(bpy.ops.sweptvol.compute(wait=True, timeout=400) == {"FINISHED"}, "compute with the pin")
    job = operators.JOBS[-1]
    first = (job.get("clearance") or [{}])[0]
    check(first.get("verdict") == "contact" and first.get("name") == "Pin" and "CONTACT" in job["line"],
          f"no certain contact with Pin: {job.get('clearance')} / {job['line']}")
    pin_map = bpy.data.objects.get("Pin clearance")
    check(pin_map is not None and pin_map.get("sweptvol_verdict") == "contact",
          "the Pin's map does not say contact")
    log(f"contact: {first['line']}; job line: {job['line']}")

    # Relative to Bar: obstacles fixed in the world are refused with it (they would move in
    # Bar's frame); then the result is parented to Bar, and in Bar's frame.
    settings.reference = bar
    select([part])
    try:
        bpy.ops.sweptvol.compute(wait=True, timeout=60)
        raise AssertionError("obstacles with a reference were not refused")
    except RuntimeError as e:
        check("is the obstacle" in str(e), f"not the refusal's words: {e}")
    settings.obstacles = None
    select([part])
    check(bpy.ops.sweptvol.compute(wait=True, timeout=400) == {"FINISHED"}, "compute relative to Bar")
    job = operators.JOBS[-1]
    job_json = json.load(open(os.path.join(job["dir"], exchange.JOB_JSON)))
    check(job_json.get("relative_to") == bar.name, f"job.json {job_json}")
    swept = bpy.data.objects.get(f"{job['label']} swept volume")
    check(swept is not None and swept.parent == bar, f"the relative result does not follow Bar: {swept}")
    sv, swept_tris = world_mesh(swept)
    start, end, step = FRAMES
    for f in (start, (start + end) / 2, end):  # the part at a sampled frame is inside, seen in the world
        scene.frame_set(int(math.floor(f)), subframe=f - math.floor(f))
        sv, swept_tris = world_mesh(swept)
        verts, _ = world_mesh(part)
        wn = winding_numbers(verts, swept_tris)
        check(wn.min() >= 0.5, f"relative: the part at frame {f} leaves the result (winding {wn.min()})")
    scene.frame_set(1)
    check(bpy.data.objects.get(f"{bar.name} clearance") is not None, "no clearance map of the reference")
    settings.reference = None
    log("relative to Bar: the result follows Bar and holds the part at frames 1, 5, 9")


def main(state):
    # ---------------------------------------------------------------------------------------------
    # Install and configure the add-on from the zip, in the fresh profile

    state["module"] = module = install_addon()
    addon = importlib.import_module(module)
    exchange = importlib.import_module(module + ".exchange")
    state["daemon"] = daemon = importlib.import_module(module + ".daemon")
    state["operators"] = operators = importlib.import_module(module + ".operators")
    jobs = os.path.join(os.path.abspath(args.work), "jobs")
    os.makedirs(jobs, exist_ok=True)
    configure(module, jobs, auto_start=True)
    log(f"add-on installed ({args.mode}) and enabled from {args.zip} as module '{module}' "
        f"({addon.__file__}), Blender {bpy.app.version_string} ({bpy.app.binary_path or 'bpy module'})")

    # ---------------------------------------------------------------------------------------------
    # The scene

    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    scene = bpy.context.scene




    # A parent empty that moves and turns; its child (a non-uniformly scaled box) turns on its own.
    carrier = bpy.data.objects.new("Carrier", None)
    scene.collection.objects.link(carrier)
    carrier.scale = (1.2, 1.2, 1.2)
    key(carrier, 1, loc=(0, 0, 0), rot=(0, 0, 0))
    key(carrier, 9, loc=(1.0, 0.5, 0.3), rot=(0, 0, 60))

    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.4, 0, 0))
    part = bpy.context.active_object
    part.name = "Part"
    part.scale = (1.5, 0.5, 0.8)
    scene.frame_set(5)  # parent while the carrier is posed: a non-identity parent inverse
    part.parent = carrier
    part.matrix_parent_inverse = carrier.matrix_world.inverted()
    key(part, 1, loc=(0.4, 0, 0), rot=(0, 0, 0))
    key(part, 9, loc=(0.6, 0.1, 0.2), rot=(90, 0, 30))

    # A second object with its own animation and a rigid modifier (bevel), scaled 0.7.
    bpy.ops.mesh.primitive_cylinder_add(vertices=12, radius=0.3, depth=1.0, location=(-1.5, 0, 0))
    bar = bpy.context.active_object
    bar.name = "Bar, the second"  # a comma: the CSV must quote the node name
    bar.scale = (0.7, 0.7, 0.7)
    bev = bar.modifiers.new("Bevel", "BEVEL")
    bev.width = 0.05
    key(bar, 1, loc=(-1.5, 0, 0), rot=(0, 0, 0))
    key(bar, 9, loc=(-1.0, 0.8, 0.5), rot=(45, 30, 0))
    clamp = bar.constraints.new("LIMIT_LOCATION")  # constraints count: x stops at -1.2
    clamp.use_max_x, clamp.max_x = True, -1.2

    # A deforming object (animated shape key): must be refused by name and cause.
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1, radius=0.3, location=(0, -2, 0))
    blob = bpy.context.active_object
    blob.name = "Blob"
    blob.shape_key_add(name="Basis")
    sk = blob.shape_key_add(name="Squash")
    for v in sk.data:
        v.co.z *= 0.3
    sk.value = 0.0
    sk.keyframe_insert("value", frame=1)
    sk.value = 1.0
    sk.keyframe_insert("value", frame=9)

    scene.frame_start, scene.frame_end = 1, 9
    scene.frame_set(1)
    settings = scene.sweptvol
    settings.use_scene_range = False
    settings.frame_start, settings.frame_end, settings.frame_step = FRAMES
    settings.accuracy = "RESOLUTION"
    settings.resolution = args.resolution




    # ---------------------------------------------------------------------------------------------
    # 1. The deforming object is refused, naming it and the cause, and nothing is submitted

    select([part, blob])
    try:
        bpy.ops.sweptvol.compute(wait=True, timeout=60)
        raise AssertionError("the deforming object was not refused")
    except RuntimeError as e:
        msg = str(e)
        log("refused as expected:", msg.strip())
        check("'Blob'" in msg and "shape keys" in msg, f"the refusal should name Blob and shape keys: {msg}")
    check(not [n for n in os.listdir(jobs) if not n.startswith(".")],
          f"a refused job left files: {os.listdir(jobs)}")

    # ---------------------------------------------------------------------------------------------
    # 2. Compute: export -> job folder -> daemon (started by the add-on) -> import

    select([part, bar])
    t0 = time.monotonic()
    result = bpy.ops.sweptvol.compute(wait=True, timeout=400)
    check(result == {"FINISHED"}, f"compute returned {result}")
    log(f"computed and imported in {time.monotonic() - t0:.1f} s")
    job = operators.JOBS[-1]
    check(job["state"] == "done", f"job state {job['state']}")
    check(daemon.alive(jobs)[0], "the add-on did not start a daemon (no heartbeat)")
    csv_text = open(os.path.join(job["dir"], exchange.TRAJECTORY)).read()
    check('"Bar, the second"' in csv_text, "the node name with a comma is not quoted in the CSV")
    job_json = json.load(open(os.path.join(job["dir"], exchange.JOB_JSON)))
    check(job_json.get("resolution") == args.resolution and job_json.get("backend") == "cpu",
          f"job.json {job_json}")

    coll = bpy.data.collections.get("Swept Volumes")
    check(coll is not None and coll.name in scene.collection.children,
          "no 'Swept Volumes' collection in the scene")
    check(len(coll.objects) == 1, f"expected one imported object, got {[o.name for o in coll.objects]}")
    swept = coll.objects[0]
    check("Part" in swept.name, f"the imported object is not named after the source: {swept.name}")
    bound = float(swept["sweptvol_hausdorff_bound"])
    check(bound > 0 and swept.get("sweptvol_triangles", 0) > 0 and swept.get("sweptvol_poses", 0) > 0,
          f"custom properties missing: {dict(swept.items())}")
    mat = swept.data.materials[0]
    blended = (mat.surface_render_method == "BLENDED" if hasattr(mat, "surface_render_method")
               else mat.blend_method == "BLEND")
    check(blended and mat.diffuse_color[3] < 1.0, "the material is not semi-transparent")
    log(f"imported '{swept.name}': {len(swept.data.polygons)} faces, bound {bound:.4g}, "
        f"poses {swept['sweptvol_poses']}")

    # ---------------------------------------------------------------------------------------------
    # 3. Geometry checks in Blender world coordinates


    non_manifold_check(swept)
    sv, swept_tris = world_mesh(swept)
    check(len(swept_tris) > 0, "the imported mesh is empty")
    check(abs(winding_numbers(np.array([[100.0, 100.0, 100.0]]), swept_tris)[0]) < 1e-6,
          "the imported mesh is not closed (winding number far away is not 0)")

    start, end, step = FRAMES
    frames = [start + k * step for k in range(int(round((end - start) / step)) + 1)]
    posed_points, posed_tris = [], []
    for f in frames:
        scene.frame_set(int(math.floor(f)), subframe=f - math.floor(f))
        for obj in (part, bar):
            verts, tris = world_mesh(obj)
            posed_points += [verts, tris.mean(axis=1)]
            posed_tris.append(tris)
    scene.frame_set(1)
    points = np.concatenate(posed_points)
    all_tris = np.concatenate(posed_tris)
    wn = winding_numbers(points, swept_tris)
    outside = np.flatnonzero(wn < 0.5)
    log(f"inside check: {len(points)} posed points over {len(frames)} frames, winding numbers "
        f"{wn.min():.4f}..{wn.max():.4f}")
    check(len(outside) == 0, f"{len(outside)} posed points are outside the swept volume, e.g. "
          f"{points[outside[:3]].tolist()} (winding {wn[outside[:3]].tolist()})")
    dist = point_triangle_distance(sv, all_tris)
    log(f"bound check: {len(sv)} mesh vertices, farthest {dist.max():.5g} from the posed objects, "
        f"bound {bound:.5g}")
    check(dist.max() <= bound + 1e-6, f"an imported vertex is {dist.max()} from the posed objects, "
          f"beyond the reported bound {bound} (at {sv[dist.argmax()].tolist()})")

    # ---------------------------------------------------------------------------------------------
    # 4. Depth images open readable; import_result works on its own

    check(bpy.ops.sweptvol.open_depth_images() == {"FINISHED"}, "open_depth_images failed")
    imgs = [i for i in bpy.data.images if "depth-" in i.name]
    check(len(imgs) == 6, f"expected 6 depth images, got {[i.name for i in imgs]}")
    for img in imgs:
        px = np.empty(img.size[0] * img.size[1] * img.channels, dtype=np.float32)
        img.pixels.foreach_get(px)
        px = px.reshape(-1, img.channels)[:, 0]
        check(img.size[0] > 0 and np.isfinite(px).all() and px.max() > 0.05,
              f"{img.name}: not readable in Blender (size {tuple(img.size)}, max {px.max()})")
    log("depth images readable:", ", ".join(f"{i.name} {tuple(i.size)}" for i in imgs))
    check(bpy.ops.sweptvol.import_result(job=job["dir"]) == {"FINISHED"}, "import_result failed")
    check(len(coll.objects) == 1, "re-importing should replace the earlier result")

    # ---------------------------------------------------------------------------------------------
    # 4a. An import that fails shows its own error, never the daemon's "done" message

    broken = os.path.join(args.work, "broken-job")
    shutil.copytree(job["dir"], broken)
    with open(os.path.join(broken, exchange.MESH), "r+b") as f:
        f.truncate(40)
    done_message = (exchange.read_status(broken) or {}).get("message", "")
    try:
        bpy.ops.sweptvol.import_result(job=broken)
        raise AssertionError("importing a truncated swept.glb should fail")
    except RuntimeError as e:
        check("importing the swept volume failed" in str(e)
              and (not done_message or done_message not in str(e)),
              f"not the import's own error: {e}")
        log("import failure reported:", str(e).strip())
    fake = dict(job, dir=broken, state="running", line="running", error="")
    check(operators.update_job(fake) and fake["state"] == "failed"
          and fake["line"].startswith("importing the swept volume failed"),
          f"the panel's line for a failed import is not its error: {fake['line']!r}")

    # ---------------------------------------------------------------------------------------------
    # 4b. A job the daemon refuses: its message comes back as a Blender error report

    select([part, bar])
    settings.accuracy, settings.tolerance = "TOLERANCE", 1e-6
    try:
        bpy.ops.sweptvol.compute(wait=True, timeout=120)
        raise AssertionError("a tolerance of 1e-6 should fail in the daemon")
    except RuntimeError as e:
        # The daemon's message, worded by the panel's field (exchange.failure_text).
        check("sweptvol failed" in str(e) and "larger Tolerance" in str(e)
              and "change Tolerance in the Swept Volume panel" in str(e),
              f"not the daemon's message in the panel's terms: {e}")
        log("daemon error reported:", str(e).strip())
    check(operators.JOBS[-1]["state"] == "failed", f"state {operators.JOBS[-1]['state']}")
    settings.accuracy = "RESOLUTION"

    # ---------------------------------------------------------------------------------------------
    # 4c. Continuous motion: between the samples the imported result encloses the object

    continuous_motion(scene, settings, operators, exchange, coll)
    articulated(scene, settings, operators, exchange, coll)

    # ---------------------------------------------------------------------------------------------
    # 4d. Clearance: obstacles, a contact, motion relative to another object

    clearance(scene, settings, operators, exchange, coll, part, bar, all_tris)

    # ---------------------------------------------------------------------------------------------
    # 5. Cancel: a big job submitted without waiting, cancelled, ends `cancelled`

    settings.resolution = 1024
    select([part, bar])
    check(bpy.ops.sweptvol.compute(wait=False) == {"FINISHED"}, "submitting without waiting failed")
    big = operators.JOBS[-1]
    deadline = time.monotonic() + 60
    while (exchange.read_status(big["dir"]) or {}).get("state") != "running" and time.monotonic() < deadline:
        time.sleep(0.1)
    check(bpy.ops.sweptvol.cancel() == {"FINISHED"}, "cancel failed")
    check(operators.wait_for(big, 60), "the cancelled job did not finish within 60 s")
    check(big["state"] == "cancelled", f"the cancelled job ended {big['state']}")
    log("cancel: job ended", big["state"])

    # ---------------------------------------------------------------------------------------------
    # 6. Disabling the add-on stops the daemon it started

    bpy.ops.preferences.addon_disable(module=module)
    beat = exchange.read_json(daemon.heartbeat_path(jobs)) or {}
    check(beat.get("state") == "stopped", f"the daemon did not stop cleanly: {beat}")

    # ---------------------------------------------------------------------------------------------
    # 7. With auto_start off and no daemon, the button still submits and says no daemon runs

    bpy.ops.preferences.addon_enable(module=module)
    # Every RNA reference taken before the re-enable is dead (a crash on 5.0, a silent no-op
    # elsewhere): fetch the preferences, the scene, its settings and the objects anew.
    configure(module, jobs, auto_start=False)
    scene = bpy.context.scene
    settings = scene.sweptvol
    settings.resolution = args.resolution
    check(settings.resolution == args.resolution, "the re-fetched settings did not take the value")
    part = bpy.data.objects["Part"]
    select([part])
    before = set(os.listdir(jobs))
    try:
        bpy.ops.sweptvol.compute(wait=True, timeout=5)
        raise AssertionError("waiting without a daemon should fail")
    except RuntimeError as e:
        check("no sweptvol daemon seems to be running" in str(e), f"no 'no daemon' message: {e}")
    new = [n for n in set(os.listdir(jobs)) - before if not n.startswith(".")]
    check(len(new) == 1 and os.path.isfile(os.path.join(jobs, new[0], exchange.TRAJECTORY)),
          f"the job was not submitted without a daemon: {new}")
    check(not daemon.alive(jobs)[0], "a daemon was started although auto_start is off")
    log("auto_start off: job submitted, no daemon started, the user is told")
    bpy.ops.preferences.addon_disable(module=module)
    check(not hasattr(bpy.types.Scene, "sweptvol"), "disabling the add-on left Scene.sweptvol")



def run():
    state = {}
    code, verdict = 1, "FAIL"
    t0 = time.monotonic()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            main(state)
        ours = [w for w in caught if "sweptvol_addon" in str(w.filename)]
        for w in ours:
            log(f"warning from the add-on: {w.filename}:{w.lineno}: {w.category.__name__}: {w.message}")
        if ours:
            DEFERRED.append(f"{len(ours)} warning(s) from the add-on's code (see above)")
        check(not DEFERRED, "; ".join(DEFERRED))
        code, verdict = 0, "PASS"
    except BaseException as e:  # noqa: BLE001 (the verdict must be printed whatever happened)
        traceback.print_exc()
        verdict = f"FAIL: {type(e).__name__}: {e}"
    finally:
        try:  # never leave a daemon behind: os._exit skips the add-on's atexit hook
            if state.get("daemon") is not None:
                state["daemon"].stop()
        except Exception:  # noqa: BLE001
            traceback.print_exc()
        log(f"{verdict} (Blender {bpy.app.version_string}, {args.mode} install, "
            f"{time.monotonic() - t0:.1f} s)")
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


run()
