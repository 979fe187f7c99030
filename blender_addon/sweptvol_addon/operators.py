"""Operators: compute (export -> job folder), cancel, import the result, open the depth images.

The bpy edge of the add-on; the protocol itself lives in `exchange.py`, starting and stopping the
daemon in `daemon.py` (both without bpy).
"""

import math
import os
import time

import bpy
import numpy as np

from . import compat, daemon, exchange, prefs, sampling

COLLECTION = "Swept Volumes"
MATERIAL = "sweptvol swept volume"
MAP_MATERIAL = "sweptvol clearance"
MAP_VALUES = "clearance"  # per vertex: the clearance's guaranteed lower end (scene units)
MAP_COLOURS = "clearance colour"
POLL_SECONDS = 0.5

# Jobs submitted in this session: dicts with dir, label, sources, scene, line, state, imported.
JOBS = []


# ---------------------------------------------------------------------------------------------
# The daemon (process control is daemon.py; this is only where the preferences come in)


def ensure_daemon(p, folder):
    """Start `sweptvol watch folder` if none runs and auto_start is on (daemon.ensure).
    Returns (ok, message): message is a warning for the user, or ''."""
    return daemon.ensure(folder, prefs.binary_path(p), p.auto_start)


# ---------------------------------------------------------------------------------------------
# Sampling the animation


def frame_samples(start, end, step):
    if not step > 0:
        raise ValueError("the frame step must be positive")
    if end < start:
        raise ValueError("the last frame is before the first")
    n = int(math.floor((end - start) / step + 1e-9))
    return [start + k * step for k in range(n + 1)]


def set_frame(scene, f):
    whole = math.floor(f)
    scene.frame_set(int(whole), subframe=float(f - whole))


def _mesh_coords(obj, depsgraph):
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    try:
        co = np.empty(len(mesh.vertices) * 3, dtype=np.float64)
        mesh.vertices.foreach_get("co", co)
        ntris = sum(len(p.vertices) - 2 for p in mesh.polygons)
    finally:
        ev.to_mesh_clear()
    return co.reshape(-1, 3), ntris


def deform_cause(obj):
    """Why an object's evaluated mesh may change over time (for the refusal message)."""
    mods = [m for m in obj.modifiers if m.show_viewport]
    arm = [m for m in mods if m.type == "ARMATURE"]
    if arm:
        return f"its Armature modifier '{arm[0].name}' deforms it"
    keys = obj.data.shape_keys if obj.type == "MESH" else None
    if keys is not None and len(keys.key_blocks) > 1:
        return "its shape keys change it"
    if mods:
        return "its modifier(s) " + ", ".join(f"'{m.name}' ({m.type.lower()})" for m in mods) + " change it"
    return "its mesh changes over time (drivers or animated mesh data)"


def evaluate(context, objects, frames, ref):
    """World matrices (Blender space) of each object at each frame, with the rigid check against
    the first evaluated mesh of each object (kept in `ref`: {name: (local vertices, tolerance)}).
    Returns {frame: {name: 4x4 array}} or raises ValueError naming the object and the cause."""
    scene = context.scene
    out = {}
    for f in frames:
        set_frame(scene, f)
        depsgraph = context.evaluated_depsgraph_get()
        out[f] = {}
        for o in objects:
            ev = o.evaluated_get(depsgraph)
            out[f][o.name] = np.array(ev.matrix_world, dtype=np.float64)
            _check_rigid(o, depsgraph, f, ref)
    return out


def _check_rigid(o, depsgraph, f, ref):
    """Hold `o`'s evaluated mesh at frame f to its first one (kept in `ref`), or raise."""
    co, ntris = _mesh_coords(o, depsgraph)
    if o.name not in ref:
        if ntris == 0:
            raise ValueError(f"'{o.name}' has no faces at frame {f:g}: nothing to sweep")
        size = float(np.linalg.norm(co.max(axis=0) - co.min(axis=0))) if len(co) else 0.0
        ref[o.name] = (co, 1e-5 * max(size, 1e-6))
        return
    co0, tol = ref[o.name]
    if co.shape != co0.shape:
        raise ValueError(f"'{o.name}' cannot be swept as a rigid part: its vertex count "
                         f"changes at frame {f:g} ({deform_cause(o)})")
    err = float(np.abs(co - co0).max()) if len(co) else 0.0
    if err > tol:
        raise ValueError(f"'{o.name}' cannot be swept as a rigid part: its mesh deforms "
                         f"(by {err:.3g} at frame {f:g}); {deform_cause(o)}. Apply or "
                         "remove the deformation, parent the mesh to one bone instead of "
                         "skinning it (Ctrl+P > Bone), or sweep a rigid proxy")


# ---------------------------------------------------------------------------------------------
# Articulated motion: parented objects and bones as a kinematic tree, rows in parent space


def rig_tree(objects):
    """The kinematic tree above the swept objects, parents first: dicts with `name` (the glTF
    node's), `parent` (an index into the list, or None), `obj` (the object, or the armature of
    a bone), `bone` (a bone's name, or None) and `mesh` (True for a swept object). Empty when no
    swept object has a parent: then world-space rows say everything."""
    if not any(o.parent is not None for o in objects):
        return []
    tree, index = [], {}

    def add(key, name, parent, obj, bone):
        index[key] = len(tree)
        tree.append({"name": name, "parent": parent, "obj": obj, "bone": bone, "mesh": False})
        return index[key]

    def of_object(o):
        if ("OB", o.name) in index:
            return index[("OB", o.name)]
        parent = None
        if o.parent is not None:
            if o.parent_type == "BONE" and o.parent.type == "ARMATURE" and o.parent_bone:
                parent = of_bone(o.parent, o.parent_bone)
            else:
                parent = of_object(o.parent)
        return add(("OB", o.name), o.name, parent, o, None)

    def of_bone(arm, name):
        if ("BONE", arm.name, name) in index:
            return index[("BONE", arm.name, name)]
        bone = arm.data.bones.get(name)
        if bone is None:
            raise ValueError(f"'{arm.name}' has no bone '{name}' to parent to")
        parent = of_bone(arm, bone.parent.name) if bone.parent else of_object(arm)
        return add(("BONE", arm.name, name), f"{arm.name}:{name}", parent, arm, name)

    for o in objects:
        tree[of_object(o)]["mesh"] = True
    names = [t["name"] for t in tree]
    if len(set(names)) != len(names):
        raise ValueError("two nodes of the rig would share a name (an object named like "
                         "'Armature:Bone'): rename it")
    return tree


def _node_world(node, depsgraph):
    """A tree node's world matrix (Blender space) at the depsgraph's frame."""
    ev = node["obj"].evaluated_get(depsgraph)
    world = np.array(ev.matrix_world, dtype=np.float64)
    if node["bone"] is None:
        return world
    pose = ev.pose if ev.pose is not None else node["obj"].pose
    return world @ np.array(pose.bones[node["bone"]].matrix, dtype=np.float64)


def evaluate_rig(context, objects, frames, ref, tree):
    """({frame: {node name: world}}, {frame: {node name: local}}) for every node of `tree` at
    each frame (Blender space; local = parent's world⁻¹ · world), with the rigid check of
    `evaluate` on the swept objects."""
    scene = context.scene
    worlds, locals_ = {}, {}
    for f in frames:
        set_frame(scene, f)
        depsgraph = context.evaluated_depsgraph_get()
        for o in objects:
            _check_rigid(o, depsgraph, f, ref)
        w = [_node_world(n, depsgraph) for n in tree]
        worlds[f] = {n["name"]: w[i] for i, n in enumerate(tree)}
        locals_[f] = {}
        for i, n in enumerate(tree):
            p = n["parent"]
            locals_[f][n["name"]] = w[i] if p is None else np.linalg.solve(w[p], w[i])
    return worlds, locals_


def rig_vertices(tree, worlds, frame, ref):
    """{node name: the vertices of every swept object under the node, in the node's frame at
    `frame`} (`ref` holds each object's local vertices)."""
    out = {}
    for i, n in enumerate(tree):
        pts = []
        for j, m in enumerate(tree):
            if not m["mesh"]:
                continue
            k = j
            while k is not None and k != i:
                k = tree[k]["parent"]
            if k is None:
                continue
            co = ref[m["name"]][0]
            rel = np.linalg.solve(worlds[frame][n["name"]], worlds[frame][m["name"]])
            pts.append(co @ rel[:3, :3].T + rel[:3, 3])
        out[n["name"]] = np.concatenate(pts) if pts else np.zeros((0, 3))
    return out


def deviation_threshold(options, placements, vertices):
    """The deviation from the screw motion allowed at a probe (sampling.threshold_for_*)."""
    if "tolerance" in options:
        return sampling.threshold_for_tolerance(options["tolerance"])
    extent = sampling.posed_extent(placements, vertices)
    if not extent > 0.0:
        raise ValueError("the selected objects have no extent: nothing to sweep")
    return sampling.threshold_for_resolution(extent, options["resolution"])


def sample(context, objects, frames, options, halvings, tree=()):
    """Each object's frames and world matrices (Blender space), and the sampling record.

    With continuous motion the frames of each object are refined where Blender's motion strays
    from the screw motion the daemon covers (sampling.refine, at most `halvings` halvings of the
    step); with discrete motion every object keeps the given frames and the record is None.
    With a rig `tree` (rig_tree) the placements are each node's local matrix, refined where a
    node strays from the screw in its parent's frame, each by the threshold over the tree's
    depth (the deviations of a chain add up).
    Returns ({name: [frame]}, {frame: {name: 4x4}}, record or None)."""
    ref = {}
    if tree:
        return _sample_rig(context, objects, frames, options, halvings, tree, ref)
    placements = evaluate(context, objects, frames, ref)
    if options.get("motion") == "discrete" or len(frames) < 2:
        return {o.name: list(frames) for o in objects}, placements, None
    vertices = {name: co for name, (co, _) in ref.items()}
    threshold = deviation_threshold(options, placements, vertices)
    records = sampling.refine(
        frames, placements, lambda fs: evaluate(context, objects, fs, ref), vertices, threshold,
        halvings)
    step = frames[1] - frames[0]
    record = sampling.summary(records, threshold, step, halvings)
    return {name: rec.frames for name, rec in records.items()}, placements, record


def _sample_rig(context, objects, frames, options, halvings, tree, ref):
    worlds, placements = evaluate_rig(context, objects, frames, ref, tree)
    if options.get("motion") == "discrete" or len(frames) < 2:
        return {n["name"]: list(frames) for n in tree}, placements, None
    meshes = {o.name: ref[o.name][0] for o in objects}
    placed = {f: {name: by_name[name] for name in meshes} for f, by_name in worlds.items()}
    threshold = deviation_threshold(options, placed, meshes)
    depth = 1
    for n in tree:
        d, p = 1, n["parent"]
        while p is not None:
            d, p = d + 1, tree[p]["parent"]
        depth = max(depth, d)
    vertices = rig_vertices(tree, worlds, frames[0], ref)
    records = sampling.refine(
        frames, placements, lambda fs: evaluate_rig(context, objects, fs, ref, tree)[1], vertices,
        threshold / depth, halvings)
    step = frames[1] - frames[0]
    record = sampling.summary(records, threshold / depth, step, halvings)
    return {name: rec.frames for name, rec in records.items()}, placements, record


def unresolved_warning(record):
    """A warning for the user where the halving limit left an interval off the screw, or ''."""
    if not record or not record["unresolved"]:
        return ""
    worst = max(((o["object"], u) for o in record["objects"] for u in o["unresolved"]),
                key=lambda x: x[1][2])
    name, (a, b, dev) = worst
    n = record["max_halvings"]
    limit = f"even after {n} halving{'s' if n > 1 else ''}" if n else "with Halvings at 0"
    return (f"'{name}' moves up to {dev:.3g} off the continuous motion the sweep covers between "
            f"frames {a:g} and {b:g} {limit} (allowed: {record['threshold']:.3g}; "
            f"{record['unresolved']} interval(s) in all): lower the frame step or raise Halvings")


# ---------------------------------------------------------------------------------------------
# Submitting


def _one_line(e):
    """An exception as one line for a report (see compat.one_line)."""
    return compat.one_line(str(e)) or type(e).__name__


def gltf_exporter_properties():
    """{identifier: None, or the enum's identifiers} of this Blender's glTF export operator."""
    try:
        props = bpy.ops.export_scene.gltf.get_rna_type().properties
    except (AttributeError, KeyError, RuntimeError) as e:
        raise RuntimeError("the glTF exporter is not available: enable the bundled "
                           f"'glTF 2.0 format' add-on ({_one_line(e)})") from e
    return {p.identifier: ({i.identifier for i in p.enum_items} if p.type == "ENUM" else None)
            for p in props}


def export_generator(context, objects, path):
    """glTF export of exactly `objects` (one node each, modifiers applied) at the current frame."""
    view_layer = context.view_layer
    old_sel = [o for o in view_layer.objects if o.select_get()]
    old_active = view_layer.objects.active
    try:
        for o in old_sel:
            o.select_set(False)
        for o in objects:
            o.select_set(True)
        view_layer.objects.active = objects[0]
        options = compat.gltf_export_options(gltf_exporter_properties(), path)
        try:
            result = bpy.ops.export_scene.gltf(**options)
        except (TypeError, RuntimeError) as e:  # a refused option, or the exporter's own error
            raise RuntimeError(f"the glTF export failed: {_one_line(e)}") from e
        if "FINISHED" not in result or not os.path.isfile(path):
            raise RuntimeError(f"the glTF export did not finish ({', '.join(sorted(result))})")
    finally:
        for o in objects:
            o.select_set(False)
        for o in old_sel:
            o.select_set(True)
        view_layer.objects.active = old_active


def submit(context, objects, frames, options, halvings=sampling.DEFAULT_HALVINGS,
           obstacles=(), reference=None):
    """Sample (and refine), export, write rows, job.json and the sampling record, commit.
    `obstacles` (objects) are exported as obstacles.glb and measured against the result
    (job.json `against`); with a `reference` object every other object is swept in its frame
    (`relative_to`): it is exported and sampled with them, each at every frame any has.
    Returns (job folder, sampling record or None). Raises on error (ValueError for the user's
    data, OSError for the folder)."""
    both = sorted({o.name for o in objects} & {o.name for o in obstacles})
    if both:
        raise ValueError(f"{', '.join(both)}: an object cannot be both swept and an obstacle "
                         "(remove it from the selection or from the Obstacles collection)")
    if reference is not None:
        if obstacles:
            raise ValueError(f"with 'Relative to' set, '{reference.name}' is the obstacle: the "
                             "results are in its frame, where other obstacles would move; clear "
                             "Obstacles or Relative to")
        if reference.name in {o.name for o in obstacles}:
            raise ValueError(f"'{reference.name}' is the reference, which is an obstacle already: "
                             "remove it from the Obstacles collection")
        objects = [o for o in objects if o.name != reference.name] + [reference]
        if len(objects) < 2:
            raise ValueError("select the objects to sweep relative to the reference, besides it")
        options = dict(options, relative_to=reference.name)
    # Parents and bones go as a hierarchy with rows in parent space; relative to a reference
    # the rows are world-space (the daemon reads them in the reference's frame), refined where
    # the motion strays from the screw.
    tree = rig_tree(objects) if reference is None else []
    p = prefs.get(context)
    folder = prefs.watch_folder(p)
    if not folder:
        raise ValueError("set the watched folder in the add-on preferences")
    os.makedirs(folder, exist_ok=True)
    scene = context.scene
    old_frame, old_sub = scene.frame_current, scene.frame_subframe
    partial = None
    try:
        object_frames, placements, record = sample(context, objects, frames, options, halvings,
                                                   tree)
        if reference is not None:
            # Relative rows pair by time: every object at every frame any of them has (the
            # refinement evaluated every object at each of them).
            union = sorted({f for fs in object_frames.values() for f in fs})
            object_frames = {name: union for name in object_frames}
        label = "+".join(o.name for o in objects)
        name = exchange.job_name(label, folder)
        partial = exchange.begin_job(folder, name)
        # Export at the first sampled frame; the rows do not depend on it (W is read back).
        set_frame(scene, frames[0])
        glb = os.path.join(partial, exchange.GENERATOR_GLB)
        export_generator(context, objects, glb)
        if obstacles:
            export_generator(context, list(obstacles), os.path.join(partial, exchange.OBSTACLES_GLB))
            options = dict(options, against=[exchange.OBSTACLES_GLB])
        doc, binary = exchange.read_glb(glb)
        if tree:
            # The rig: nodes with their local matrices, rows in parent space.
            first = placements[frames[0]]
            rig = [(n["name"], n["parent"], exchange.blender_to_gltf(first[n["name"]].tolist()),
                    n["name"] if n["mesh"] else None) for n in tree]
            with open(glb, "wb") as f:
                f.write(exchange.write_glb(exchange.rig_document(doc, rig), binary))
            rows = [(f, n["name"], exchange.blender_to_gltf(placements[f][n["name"]].tolist()))
                    for n in tree for f in object_frames[n["name"]]]
            options = dict(options, name=label[:200], rows="local")
            exchange.write_job_inputs(partial, exchange.trajectory_csv(rows, local=True), options,
                                      record)
            job_dir = exchange.commit_job(partial)
            partial = None
            return job_dir, record
        placed = {}
        for node_name, w in exchange.mesh_node_worlds(doc):
            placed.setdefault(node_name, []).append(w)
        rows = []
        for o in objects:
            if len(placed.get(o.name, [])) != 1:
                raise ValueError(f"the glTF exporter wrote {len(placed.get(o.name, []))} mesh nodes "
                                 f"named '{o.name}' (expected one)")
            w = placed[o.name][0]
            for f in object_frames[o.name]:  # the object's own (refined) frames, in order
                m = placements[f][o.name].tolist()
                rows.append((f, o.name, exchange.trajectory_row(m, w)))
        options = dict(options, name=label[:200])
        exchange.write_job_inputs(partial, exchange.trajectory_csv(rows), options, record)
        job_dir = exchange.commit_job(partial)
        partial = None
        return job_dir, record
    finally:
        if partial is not None:
            exchange.abandon_job(partial)
        scene.frame_set(old_frame, subframe=old_sub)


# ---------------------------------------------------------------------------------------------
# Results


def _material():
    mat = bpy.data.materials.get(MATERIAL)
    if mat is None:
        mat = bpy.data.materials.new(MATERIAL)
        mat.diffuse_color = (0.15, 0.55, 1.0, 0.3)  # solid view: semi-transparent
        if mat.node_tree is None:  # up to 4.5 a new material has no nodes; 5.0 always has them
            mat.use_nodes = True  # (5.0 deprecates use_nodes: not touched where not needed)
        nodes = mat.node_tree.nodes if mat.node_tree is not None else None
        bsdf = nodes.get("Principled BSDF") if nodes is not None else None
        if bsdf is not None:
            for name, value in (("Base Color", (0.15, 0.55, 1.0, 1.0)), ("Alpha", 0.3)):
                socket = bsdf.inputs.get(name)
                if socket is not None:
                    socket.default_value = value
        for key, value in compat.settable(lambda k: hasattr(mat, k)):
            setattr(mat, key, value)
    return mat


def import_result(job_dir, scene=None, label=None):
    """Import `job_dir/swept.glb` into the collection "Swept Volumes" as one object named after
    the source, with the report's bound and counts as custom properties. Returns the object."""
    status = exchange.read_status(job_dir)
    if not status or status.get("state") != "done":
        raise ValueError(f"the job {os.path.basename(job_dir)} is not done "
                         f"({exchange.describe_status(status)})")
    report = exchange.read_report(job_dir) or {}
    points, tris = exchange.read_glb_mesh(os.path.join(job_dir, exchange.MESH))
    label = label or status.get("name") or os.path.basename(job_dir)
    obj_name = f"{label} swept volume"[:63]
    mesh = bpy.data.meshes.new(obj_name)
    mesh.from_pydata([exchange.gltf_point_to_blender(p) for p in points], [], tris)
    mesh.update()
    mesh.materials.append(_material())
    scene = scene or bpy.context.scene
    coll = bpy.data.collections.get(COLLECTION)
    if coll is None:
        coll = bpy.data.collections.new(COLLECTION)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    obj = coll.objects.get(obj_name)
    if obj is not None and obj.type == "MESH":
        old = obj.data
        obj.data = mesh
        if old.users == 0:
            bpy.data.meshes.remove(old)
    else:
        obj = bpy.data.objects.new(obj_name, mesh)
        coll.objects.link(obj)
    obj.show_transparent = True
    for key in [k for k in obj.keys() if k.startswith("sweptvol_")]:  # a re-import's old values
        del obj[key]
    for key, value in exchange.result_summary(report, exchange.read_sampling(job_dir)).items():
        obj[key] = value
    obj["sweptvol_job"] = job_dir
    obj["sweptvol_sources"] = label
    reference = _reference(report)
    if reference is not None:
        _attach(obj, reference)
    import_clearance(report, coll, reference)
    return obj


def _reference(report):
    """The object whose frame a relative job's outputs are in, or None."""
    name = ((report or {}).get("inputs") or {}).get("relative_to")
    return bpy.data.objects.get(name) if name else None


def _attach(obj, reference):
    """Make `obj` (in the reference's local frame) follow the reference."""
    obj.parent = reference
    obj.matrix_parent_inverse.identity()
    obj.matrix_basis.identity()


def _map_material():
    """A material that shows the clearance map's colour attribute (Color Attribute node)."""
    mat = bpy.data.materials.get(MAP_MATERIAL)
    if mat is None:
        mat = bpy.data.materials.new(MAP_MATERIAL)
        if mat.node_tree is None:
            mat.use_nodes = True
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        bsdf = nodes.get("Principled BSDF")
        attr = nodes.new("ShaderNodeAttribute")
        attr.attribute_name = MAP_COLOURS
        attr.location = (-300, 300)
        if bsdf is not None:
            links.new(attr.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def _replace(coll, name, data):
    """The object `name` in `coll` with new `data` (an earlier import's replaced), linked."""
    obj = coll.objects.get(name)
    if obj is not None and obj.type == ("MESH" if data is not None else "EMPTY"):
        if data is not None:
            old = obj.data
            obj.data = data
            if old.users == 0:
                bpy.data.meshes.remove(old)
        return obj
    obj = bpy.data.objects.new(name, data)
    coll.objects.link(obj)
    return obj


def import_clearance(report, coll, reference=None):
    """Each obstacle's clearance map as an object `NAME clearance` (the lower end of the
    clearance per vertex in the attribute `clearance`, its colour in `clearance colour`, shown by
    the material) and an empty `NAME closest point` at the obstacle's point nearest the swept
    volume; verdict and interval as custom properties. Returns the objects made."""
    made = []
    seen = set()
    by_name = {e["name"]: e for e in exchange.clearance_lines(report)}
    for entry in ((report or {}).get("clearance") or {}).get("obstacles", []):
        path = entry.get("map")
        if not path or path in seen or not os.path.isfile(path):
            continue
        seen.add(path)
        for o in exchange.read_clearance_map(path):
            name = f"{o['name']} clearance"[:63]
            mesh = bpy.data.meshes.new(name)
            mesh.from_pydata([exchange.gltf_point_to_blender(p) for p in o["points"]], [], o["tris"])
            mesh.update()
            values = mesh.attributes.new(MAP_VALUES, "FLOAT", "POINT")
            values.data.foreach_set("value", [float(v) for v in o["values"]])
            colours = mesh.color_attributes.new(MAP_COLOURS, "FLOAT_COLOR", "POINT")
            colours.data.foreach_set("color", [x for c in o["colours"] for x in (*c, 1.0)])
            mesh.materials.append(_map_material())
            obj = _replace(coll, name, mesh)
            line = by_name.get(o["name"], {})
            for key, value in (("sweptvol_verdict", line.get("verdict")),
                               ("sweptvol_clearance_lower", line.get("lower")),
                               ("sweptvol_clearance_upper", line.get("upper")),
                               ("sweptvol_clearance", line.get("line"))):
                if value is not None:
                    obj[key] = value
            made.append(obj)
            if o["closest"] is not None:
                marker = _replace(coll, f"{o['name']} closest point"[:63], None)
                marker.empty_display_type = "SPHERE"
                marker.empty_display_size = 0.02 * max(obj.dimensions) if max(obj.dimensions) > 0 else 0.05
                marker.location = exchange.gltf_point_to_blender(o["closest"][0])
                made.append(marker)
            if reference is not None:
                for m in made[-2:] if o["closest"] is not None else made[-1:]:
                    location = tuple(m.location)
                    _attach(m, reference)
                    m.location = location
    return made


def depth_images(job_dir):
    """Load the six depth EXRs as Blender images (their `Y` channel is what the editor shows)."""
    images = []
    for name in exchange.DEPTH_IMAGES:
        path = os.path.join(job_dir, name)
        if not os.path.isfile(path):
            continue
        img = bpy.data.images.load(path, check_existing=True)
        img.name = f"{os.path.basename(job_dir)} {name}"
        img.colorspace_settings.name = "Non-Color"
        img.reload()
        images.append(img)
    return images


def show_in_image_editor(context, image):
    """Show `image` in an image editor: the screen's own if it has one, else a new window."""
    area = next((a for a in context.screen.areas if a.type == "IMAGE_EDITOR"), None)
    if area is None:
        bpy.ops.wm.window_new()
        area = context.window_manager.windows[-1].screen.areas[0]
        area.type = "IMAGE_EDITOR"
    area.spaces.active.image = image


def last_job(state=None):
    for job in reversed(JOBS):
        if state is None or job["state"] == state:
            return job
    return None


def chosen_job(path):
    """(folder, label) of the job folder an operator was given, else of this session's last
    finished job (label None for a given folder); (None, None) when there is neither."""
    if path:
        return os.path.abspath(bpy.path.abspath(path)).rstrip(os.sep), None
    job = last_job("done")
    return (job["dir"], job["label"]) if job else (None, None)


# ---------------------------------------------------------------------------------------------
# Progress: a timer reads status.json (never blocks), and the background-mode wait


def _redraw():
    wm = bpy.context.window_manager
    for window in getattr(wm, "windows", []):
        for area in window.screen.areas:
            if area.type in ("VIEW_3D", "STATUSBAR"):
                area.tag_redraw()


def _report(level, message):
    print(f"sweptvol: {level}: {message}")
    if not bpy.app.background:
        try:
            bpy.ops.sweptvol.report_message(level=level, message=message)
        except Exception:  # no window context: the panel still shows the line
            pass


def update_job(job):
    """Refresh one job from its status.json; import when it is done. Returns True if finished."""
    if job["state"] in exchange.FINISHED:
        return True
    status = exchange.read_status(job["dir"])
    job["line"] = exchange.describe_status(status)
    job["progress"] = float((status or {}).get("progress") or 0.0)
    state = (status or {}).get("state", "submitted")
    if state not in exchange.FINISHED:
        job["state"] = state
        return False
    job["state"] = state
    if state == "done":
        try:
            scene = bpy.data.scenes.get(job["scene"]) or bpy.context.scene
            obj = import_result(job["dir"], scene, job["label"])
            job["imported"] = obj.name
            job["line"] = f"done: imported '{obj.name}'"
            _report("INFO", f"swept volume of {job['label']} imported as '{obj.name}'")
            try:
                with open(os.path.join(job["dir"], exchange.TRAJECTORY), encoding="utf-8") as f:
                    frames = exchange.frames_by_line(f.read())
            except OSError:
                frames = None
            job["clearance"] = exchange.clearance_lines(exchange.read_report(job["dir"]), frames)
            contacts = [e["line"] for e in job["clearance"] if e["verdict"] == "contact"]
            if contacts:
                job["line"] += f"; {len(contacts)} CONTACT(S)"
                _report("ERROR", "sweptvol found a certain contact: " + "; ".join(contacts))
        except Exception as e:  # noqa: BLE001 (any failure must reach the panel, worded)
            job["state"] = "failed"
            job["error"] = f"importing the swept volume failed: {type(e).__name__}: {_one_line(e)}"
            job["line"] = job["error"]
            _report("ERROR", job["error"])
    elif state == "failed":
        job["error"] = f"sweptvol failed for {job['label']}: {exchange.failure_text(status)}"
        _report("ERROR", job["error"])
    else:
        _report("WARNING", f"sweptvol job for {job['label']} cancelled")
    return True


def _poll_timer():
    busy = False
    for job in JOBS:
        if not update_job(job):
            busy = True
    _redraw()
    return POLL_SECONDS if busy else None


def start_polling():
    if not bpy.app.timers.is_registered(_poll_timer):
        bpy.app.timers.register(_poll_timer, first_interval=POLL_SECONDS)


def wait_for(job, timeout):
    """Background mode: block until the job finishes (or the timeout passes)."""
    deadline = time.monotonic() + timeout if timeout > 0 else None
    last = None
    while not update_job(job):
        if job["line"] != last:
            print(f"sweptvol: {job['label']}: {job['line']}", flush=True)
            last = job["line"]
        if deadline is not None and time.monotonic() > deadline:
            return False
        time.sleep(0.2)
    return True


# ---------------------------------------------------------------------------------------------
# Operators


class SWEPTVOL_OT_compute(bpy.types.Operator):
    """Export the selected objects and their animation and compute their swept volume"""

    bl_idname = "sweptvol.compute"
    bl_label = "Compute swept volume"
    bl_options = {"REGISTER"}

    wait: bpy.props.BoolProperty(
        name="Wait", description="Block until the job finishes (default in background mode)",
        default=False)
    timeout: bpy.props.FloatProperty(
        name="Timeout", description="Seconds to wait at most (0: no limit)", default=0.0, min=0.0)

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    def execute(self, context):
        settings = context.scene.sweptvol
        objects = [o for o in context.selected_objects if o.type == "MESH"]
        skipped = [o.name for o in context.selected_objects if o.type != "MESH"]
        if not objects:
            self.report({"ERROR"}, "select the mesh objects to sweep")
            return {"CANCELLED"}
        if skipped:
            self.report({"WARNING"}, f"not meshes, skipped: {', '.join(skipped)}")
        scene = context.scene
        if settings.use_scene_range:
            start, end, step = scene.frame_start, scene.frame_end, float(scene.frame_step)
        else:
            start, end, step = settings.frame_start, settings.frame_end, settings.frame_step
        try:
            frames = frame_samples(float(start), float(end), float(step))
        except ValueError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        p = prefs.get(context)
        options = {"backend": p.backend, "motion": settings.motion}
        obstacles = []
        if settings.obstacles is not None:
            obstacles = [o for o in settings.obstacles.all_objects if o.type == "MESH"]
        if settings.use_require_clearance:
            options["require_clearance"] = float(settings.require_clearance)
        if settings.accuracy == "TOLERANCE":
            options["tolerance"] = float(settings.tolerance)
        else:
            options["resolution"] = int(settings.resolution)
        try:
            job_dir, record = submit(context, objects, frames, options, settings.halvings,
                                     obstacles, settings.reference)
        except (ValueError, OSError, RuntimeError) as e:  # the user's data, the folder, export
            self.report({"ERROR"}, _one_line(e))
            return {"CANCELLED"}
        except Exception as e:  # noqa: BLE001 (anything else: still worded, never a traceback)
            self.report({"ERROR"}, f"submitting the job failed: {type(e).__name__}: {_one_line(e)}")
            return {"CANCELLED"}
        label = "+".join(o.name for o in objects)
        job = {"dir": job_dir, "label": label, "sources": [o.name for o in objects],
               "scene": scene.name, "state": "submitted", "line": "submitted", "progress": 0.0,
               "imported": ""}
        JOBS.append(job)
        try:
            ok, warning = ensure_daemon(p, prefs.watch_folder(p))
        except OSError as e:  # the binary cannot be run, or its log cannot be written
            ok, warning = False, (f"cannot start the daemon ({_one_line(e)}); the job waits in "
                                  "the folder")
        added = f" (+{record['rows_added']} sub-frames where the motion strays)" if record else ""
        self.report({"INFO"}, f"submitted {len(objects)} object(s), {len(frames)} frames{added}: "
                    f"{job_dir}")
        stray = unresolved_warning(record)
        if stray:
            self.report({"WARNING"}, stray)
            print(f"sweptvol: WARNING: {stray}")
        wait = self.wait if self.properties.is_property_set("wait") else bpy.app.background
        if not wait:
            if warning:
                self.report({"WARNING"}, warning)
            start_polling()
            return {"FINISHED"}
        if not ok:
            self.report({"ERROR"}, f"submitted, but not waiting for it: {warning}")
            return {"CANCELLED"}
        if not wait_for(job, self.timeout):
            self.report({"ERROR"}, f"the job did not finish within {self.timeout:g} s ({job['line']})")
            return {"CANCELLED"}
        if job["state"] == "done":
            self.report({"INFO"}, job["line"])
            return {"FINISHED"}
        if job.get("error"):  # the daemon's failure, or ours importing its result
            self.report({"ERROR"}, job["error"])
        else:
            self.report({"ERROR"}, f"sweptvol {job['state']}: {job['line']}")
        return {"CANCELLED"}


class SWEPTVOL_OT_cancel(bpy.types.Operator):
    """Ask the daemon to stop the running job(s) of this session"""

    bl_idname = "sweptvol.cancel"
    bl_label = "Cancel"

    job: bpy.props.StringProperty(name="Job folder", description="Empty: every unfinished job")

    def execute(self, context):
        targets = [j for j in JOBS if j["state"] not in exchange.FINISHED
                   and (not self.job or os.path.abspath(self.job) == j["dir"])]
        if self.job and not targets and os.path.isdir(self.job):
            targets = [{"dir": os.path.abspath(self.job), "label": os.path.basename(self.job)}]
        if not targets:
            self.report({"WARNING"}, "no unfinished sweptvol job")
            return {"CANCELLED"}
        for job in targets:
            try:
                exchange.request_cancel(job["dir"])
            except OSError as e:
                self.report({"ERROR"}, f"cannot cancel {job['label']}: {e}")
                return {"CANCELLED"}
            job["line"] = "cancelling"
        self.report({"INFO"}, f"cancel requested for {len(targets)} job(s)")
        return {"FINISHED"}


class SWEPTVOL_OT_import_result(bpy.types.Operator):
    """Import a finished job's swept volume (default: the last finished job of this session)"""

    bl_idname = "sweptvol.import_result"
    bl_label = "Import swept volume"
    bl_options = {"REGISTER", "UNDO"}

    job: bpy.props.StringProperty(name="Job folder", subtype="DIR_PATH")

    def execute(self, context):
        job_dir, label = chosen_job(self.job)
        if job_dir is None:
            self.report({"ERROR"}, "no finished sweptvol job in this session: give its folder")
            return {"CANCELLED"}
        try:
            obj = import_result(job_dir, context.scene, label)
        except Exception as e:  # noqa: BLE001 (shown worded in the panel, never a traceback)
            self.report({"ERROR"}, f"importing the swept volume failed: {type(e).__name__}: "
                        f"{_one_line(e)}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"imported '{obj.name}'")
        return {"FINISHED"}


class SWEPTVOL_OT_open_depth_images(bpy.types.Operator):
    """Open the six depth images of a finished job in the image editor"""

    bl_idname = "sweptvol.open_depth_images"
    bl_label = "Open depth images"

    job: bpy.props.StringProperty(name="Job folder", subtype="DIR_PATH")

    def execute(self, context):
        job_dir, _ = chosen_job(self.job)
        if job_dir is None:
            self.report({"ERROR"}, "no finished sweptvol job in this session: give its folder")
            return {"CANCELLED"}
        try:
            images = depth_images(job_dir)
        except (RuntimeError, OSError) as e:  # an unreadable image
            self.report({"ERROR"}, f"cannot load the depth images of {job_dir}: {_one_line(e)}")
            return {"CANCELLED"}
        if not images:
            self.report({"ERROR"}, f"no depth images in {job_dir}")
            return {"CANCELLED"}
        if not bpy.app.background and context.screen is not None:
            try:
                show_in_image_editor(context, images[0])
            except (RuntimeError, IndexError) as e:
                self.report({"WARNING"}, f"images loaded, but no image editor could be opened ({e})")
        self.report({"INFO"}, f"loaded {len(images)} depth images ({', '.join(i.name for i in images)})")
        return {"FINISHED"}


class SWEPTVOL_OT_report_message(bpy.types.Operator):
    """Show a message from a background poll as a Blender report"""

    bl_idname = "sweptvol.report_message"
    bl_label = "sweptvol message"
    bl_options = {"INTERNAL"}

    level: bpy.props.StringProperty(default="INFO")
    message: bpy.props.StringProperty()

    def execute(self, context):
        self.report({self.level}, self.message)
        return {"FINISHED"}


classes = (SWEPTVOL_OT_compute, SWEPTVOL_OT_cancel, SWEPTVOL_OT_import_result,
           SWEPTVOL_OT_open_depth_images, SWEPTVOL_OT_report_message)
