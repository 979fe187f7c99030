"""Tests of the add-on's version handling (no Blender): glTF export options chosen from what the
running exporter offers, material settings chosen from what the material has.

Run: target/test-venv/bin/python -m pytest blender_addon/tests
"""

import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "sweptvol_addon"))
import compat  # noqa: E402  (the module itself: the package __init__ needs bpy)

# The glTF exporter's properties as the real Blenders offer them (enum items; None: not an enum).
# From bpy.ops.export_scene.gltf.get_rna_type().properties; export_format's items are dynamic
# (an empty list) from 4.2 on.
COMMON = {k: None for k in (
    "filepath", "use_selection", "export_apply", "export_current_frame", "export_animations",
    "export_skins", "export_morph", "export_texcoords", "export_normals", "export_cameras",
    "export_lights", "export_extras", "export_yup", "export_attributes", "export_tangents")}
BLENDER_3_4 = dict(COMMON, export_format={"GLB", "GLTF_SEPARATE", "GLTF_EMBEDDED"},
                   export_materials={"EXPORT", "PLACEHOLDER", "NONE"}, export_colors=None)
BLENDER_4_2 = dict(COMMON, export_format=set(), export_materials={"EXPORT", "PLACEHOLDER", "NONE"},
                   export_vertex_color={"MATERIAL", "ACTIVE", "NONE"},
                   export_all_vertex_colors=None, export_active_vertex_color_when_no_material=None)
BLENDER_4_5 = dict(BLENDER_4_2, export_materials={"EXPORT", "PLACEHOLDER", "VIEWPORT", "NONE"},
                   export_vertex_color={"MATERIAL", "ACTIVE", "NAME", "NONE"},
                   export_vertex_color_name=None)


def test_3_4_gets_export_colors():
    opts = compat.gltf_export_options(BLENDER_3_4, "/tmp/x.glb")
    assert opts["filepath"] == "/tmp/x.glb" and opts["export_format"] == "GLB"
    assert opts["export_colors"] is False and "export_vertex_color" not in opts
    assert opts["use_selection"] is True and opts["export_apply"] is True and opts["export_yup"] is True
    assert opts["export_current_frame"] is True and opts["export_materials"] == "NONE"


@pytest.mark.parametrize("available", [BLENDER_4_2, BLENDER_4_5])
def test_4x_gets_export_vertex_color_and_never_export_colors(available):
    opts = compat.gltf_export_options(available, "x.glb")
    assert "export_colors" not in opts  # the 4.2 TypeError: keyword "export_colors" unrecognized
    assert opts["export_vertex_color"] == "NONE"
    assert opts["export_all_vertex_colors"] is False
    assert opts["export_active_vertex_color_when_no_material"] is False
    assert opts["export_format"] == "GLB"  # a dynamic enum (no items listed) is trusted


@pytest.mark.parametrize("available", [BLENDER_3_4, BLENDER_4_2, BLENDER_4_5])
def test_only_offered_options_are_passed(available):
    assert set(compat.gltf_export_options(available, "x.glb")) <= set(available)


def test_optional_options_are_dropped_when_absent_or_refusing_the_value():
    available = {"filepath": None, "export_format": {"GLB"}, "use_selection": None,
                 "export_apply": None, "export_yup": None, "export_materials": {"EXPORT"}}
    opts = compat.gltf_export_options(available, "x.glb")
    assert "export_materials" not in opts and "export_current_frame" not in opts
    assert set(opts) == {"filepath", "export_format", "use_selection", "export_apply", "export_yup"}


@pytest.mark.parametrize("drop", ["use_selection", "export_apply", "export_yup", "export_format"])
def test_a_missing_required_option_is_a_worded_error(drop):
    available = {k: v for k, v in BLENDER_4_5.items() if k != drop}
    with pytest.raises(compat.ExportOptionsError, match=drop):
        compat.gltf_export_options(available, "x.glb")


def test_glb_refused_by_the_exporter_is_a_worded_error():
    with pytest.raises(ValueError, match="export_format='GLB'"):
        compat.gltf_export_options(dict(BLENDER_3_4, export_format={"GLTF_SEPARATE"}), "x.glb")


def test_no_filepath_is_a_worded_error():
    with pytest.raises(ValueError, match="filepath"):
        compat.gltf_export_options({}, "x.glb")


# Material attributes per version (hasattr on a new material).
MAT_3_4 = {"blend_method", "shadow_method", "show_transparent_back"}
MAT_4_2 = MAT_3_4 | {"surface_render_method", "use_transparency_overlap"}
MAT_4_5 = MAT_4_2 - {"shadow_method"}  # the AttributeError on 4.5 and 5.0


def test_material_settings_per_version():
    assert dict(compat.settable(MAT_3_4.__contains__)) == {
        "blend_method": "BLEND", "show_transparent_back": False, "shadow_method": "NONE"}
    assert dict(compat.settable(MAT_4_2.__contains__)) == {
        "surface_render_method": "BLENDED", "use_transparency_overlap": False,
        "shadow_method": "NONE"}
    assert dict(compat.settable(MAT_4_5.__contains__)) == {
        "surface_render_method": "BLENDED", "use_transparency_overlap": False}
    assert compat.settable(lambda k: False) == []


def test_one_line():
    assert compat.one_line("Error: cannot write x\n") == "cannot write x"
    assert compat.one_line("Error: Python: Traceback (most recent call last):\n  File \"op.py\", "
                           "line 3, in execute\n    f()\nAttributeError: no shadow_method\n"
                           ) == "AttributeError: no shadow_method"
    assert compat.one_line("a JSONDecodeError: Error: b") == "a JSONDecodeError: Error: b"
    assert compat.one_line("two\nlines") == "two lines"
    assert compat.one_line("") == "" and compat.one_line("Error: \n") == ""
