"""What differs between Blender versions, decided from what the running Blender offers (no bpy
here, so it is tested without Blender; the bpy edge passes in what it found).

Never decide by version number: inspect the operator's properties or the object's attributes.
"""

# The glTF export the add-on needs: (property, wanted value). Required ones must exist (the
# export is useless without them); the optional ones only trim what gets written.
GLTF_REQUIRED = (
    ("export_format", "GLB"),
    ("use_selection", True),
    ("export_apply", True),  # modifiers applied: the swept shape is what the user sees
    ("export_yup", True),
)
GLTF_OPTIONAL = (
    ("export_current_frame", True),
    ("export_animations", False),
    ("export_skins", False),
    ("export_morph", False),
    ("export_materials", "NONE"),
    ("export_texcoords", False),
    ("export_normals", False),
    ("export_tangents", False),
    ("export_attributes", False),
    ("export_colors", False),  # up to 4.1
    ("export_vertex_color", "NONE"),  # 4.2+: replaces export_colors
    ("export_all_vertex_colors", False),
    ("export_active_vertex_color_when_no_material", False),
    ("export_cameras", False),
    ("export_lights", False),
    ("export_extras", False),
)


class ExportOptionsError(ValueError):
    """The running Blender's glTF exporter lacks an option the add-on cannot do without."""


def _accepts(choices, value):
    # choices: None (not an enum), or the enum's identifiers; an empty set is a dynamic enum
    # whose items are only known when drawn: accept the value and let the exporter decide.
    return not choices or not isinstance(value, str) or value in choices


def gltf_export_options(available, filepath):
    """Keyword arguments for bpy.ops.export_scene.gltf, from `available`: {property identifier:
    None, or the set of an enum property's identifiers} of the running Blender's exporter
    (bpy.ops.export_scene.gltf.get_rna_type().properties). Raises ExportOptionsError naming
    what is missing when a required option is absent or refuses the needed value."""
    if "filepath" not in available:
        raise ExportOptionsError("this Blender's glTF exporter has no 'filepath' option")
    options = {"filepath": filepath}
    missing = []
    for key, value in GLTF_REQUIRED:
        if key in available and _accepts(available[key], value):
            options[key] = value
        else:
            missing.append(f"{key}={value!r}")
    if missing:
        raise ExportOptionsError("this Blender's glTF exporter does not offer "
                                 + ", ".join(missing) + " (needed to export the objects)")
    for key, value in GLTF_OPTIONAL:
        if key in available and _accepts(available[key], value):
            options[key] = value
    return options


# The result's look: for each setting, alternatives (attribute, value), newest first; the first
# whose attribute the running Blender has is set, and a setting none of whose attributes exists is
# skipped. surface_render_method/use_transparency_overlap are EEVEE Next (4.2+, where
# blend_method/show_transparent_back linger as deprecated aliases); shadow_method is gone in 4.5.
MATERIAL_SETTINGS = (
    (("surface_render_method", "BLENDED"), ("blend_method", "BLEND")),
    (("use_transparency_overlap", False), ("show_transparent_back", False)),
    (("shadow_method", "NONE"),),
)


def settable(has_attr, settings=MATERIAL_SETTINGS):
    """The (attribute, value) pairs to set: per setting, its first alternative whose attribute
    exists (has_attr(name) is true)."""
    out = []
    for alternatives in settings:
        for key, value in alternatives:
            if has_attr(key):
                out.append((key, value))
                break
    return out


def one_line(message):
    """An error message as one line for a report or the panel. Errors raised by bpy.ops carry
    'Error: ' prefixes and newlines, and an operator's own Python failure carries its whole
    traceback: of that, only the last line (the exception) is kept. '' if nothing is left."""
    lines = [line.strip() for line in str(message).splitlines()]
    lines = [line[len("Error:"):].strip() if line.startswith("Error:") else line for line in lines]
    lines = [line for line in lines if line]
    if any("Traceback (most recent call last)" in line for line in lines):
        lines = lines[-1:]
    return " ".join(lines)
