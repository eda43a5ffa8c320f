"""The extension as a package: built zip contents, offline install, shipped wheels, clean (un)registration."""
from __future__ import annotations

import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))
import build_extension  # noqa: E402

OPERATORS = ["import_ct", "load_phantom", "segment", "extract_boundaries", "reconstruct_surface",
             "build_solid", "build_volume", "run_pipeline", "frame_study", "add_cutter", "remove_study"]
OUR_HANDLERS = ["depsgraph_update_post:pdehead_cutter_update", "depsgraph_update_post:pdehead_face_update",
                "frame_change_post:pdehead_frame_change",
                "frame_change_pre:pdehead_frame_change_pre", "load_post:pdehead_forensic_load_post",
                "load_post:pdehead_load_post",
                "load_post:pdehead_migrate_load_post", "load_post:pdehead_validate_load_post",
                "load_post:pdehead_volume_load_post",
                "save_post:pdehead_save_post", "save_pre:pdehead_save_pre"]
PANELS = ["PDEHEAD_PT_study", "PDEHEAD_PT_segmentation", "PDEHEAD_PT_boundaries", "PDEHEAD_PT_surface",
          "PDEHEAD_PT_solid", "PDEHEAD_PT_volume", "PDEHEAD_PT_timings"]


def test_shipped_requirements_exclude_numpy_and_follow_the_pins():
    reqs = build_extension.shipped_requirements()
    names = {r.split("==")[0] for r in reqs}
    pins = build_extension.read_pins()
    assert "numpy" not in names
    assert {"scikit-image", "scipy", "pydicom", "imageio", "lazy-loader", "networkx", "packaging", "pillow",
            "tifffile", "pylibjpeg", "pylibjpeg-openjpeg", "pylibjpeg-libjpeg"} == names
    for name in ("scikit-image", "scipy", "pydicom", "pylibjpeg", "pylibjpeg-openjpeg", "pylibjpeg-libjpeg"):
        assert f"{name}=={pins[name]}" in reqs


def test_manifest_with_wheels_is_valid_toml_and_keeps_tables():
    text = (ROOT / "blender_manifest.toml").read_text()
    out = tomllib.loads(build_extension.manifest_with_wheels(text, ["a-1-py3-none-any.whl"], ["linux-x64"]))
    assert out["wheels"] == ["./wheels/a-1-py3-none-any.whl"]
    assert out["platforms"] == ["linux-x64"]
    assert out["permissions"]["files"]
    assert out["id"] == "pdehead" and out["schema_version"] == "1.0.0"


def test_zip_contents(extension_zip):
    with zipfile.ZipFile(extension_zip) as z:
        names = z.namelist()
        manifest = tomllib.loads(z.read("blender_manifest.toml").decode())
    assert "__init__.py" in names and "operators/ui/ops.py" in names and "pdehead_addon/pde/pde_surface.py" in names
    assert "operators/study/steps.py" in names and "pdehead_addon/defaults.py" in names  # issue 13's modules ship
    assert not any(n.startswith(("tests/", "scripts/", "docs/")) or "__pycache__" in n for n in names)
    wheels = sorted(n for n in names if n.startswith("wheels/"))
    assert not any("numpy" in w for w in wheels)
    # pure-Python wheels once; compiled ones for each Blender Python: cp311 (4.2 - 5.0) and cp313 (5.1+)
    for prefix in ("pydicom-", "networkx-", "tifffile-", "imageio-", "lazy_loader-", "packaging-", "pylibjpeg-2"):
        found = [w for w in wheels if w.startswith("wheels/" + prefix)]
        assert len(found) == 1 and found[0].endswith("-py3-none-any.whl"), (prefix, wheels)
    for prefix in ("scikit_image-", "scipy-", "pillow-", "pylibjpeg_openjpeg-", "pylibjpeg_libjpeg-"):
        found = [w for w in wheels if w.startswith("wheels/" + prefix)]
        assert [Path(w).name.split("-")[2] for w in found] == ["cp311", "cp313"], (prefix, wheels)
        assert all("manylinux" in w for w in found), found
    # the builder's per-platform copy of platforms and wheels (what Blender reads from a split zip)
    generated = manifest.get("build", {}).get("generated", manifest)
    assert generated["platforms"] == ["linux-x64"]
    assert sorted("wheels/" + Path(w).name for w in generated["wheels"]) == wheels


def test_build_leaves_the_repository_clean(extension_zip):
    status = subprocess.run(["git", "status", "--porcelain", "--", "blender_manifest.toml", "build", "dist"],
                            cwd=ROOT, capture_output=True, text=True)
    assert status.returncode == 0
    assert status.stdout.strip() == ""


def test_installed_and_enabled(pdehead_ext):
    import bpy
    assert pdehead_ext.__name__ == "bl_ext.user_default.pdehead"
    installed = Path(pdehead_ext.__file__).parent
    assert Path(bpy.utils.user_resource('EXTENSIONS')) in installed.parents
    assert set(OPERATORS) <= set(dir(bpy.ops.pdehead))
    for name in PANELS:
        panel = getattr(bpy.types, name)
        assert panel.bl_category == "PDE Head" and panel.bl_space_type == 'VIEW_3D'
    # every operator has a tooltip and REGISTER + UNDO
    for name in OPERATORS:
        cls = getattr(bpy.types, "PDEHEAD_OT_" + name)
        assert cls.bl_description.strip(), name
        assert {'REGISTER', 'UNDO'} <= set(cls.bl_options), name
    # the engine imports from inside the extension
    engine = sys.modules[pdehead_ext.__name__ + ".pdehead_addon"]
    assert Path(engine.__file__).parent == installed / "pdehead_addon"


def test_every_setting_operator_option_and_preference_reads_the_defaults_table(pdehead_ext):
    """pdehead_addon/defaults.py is the one owner: the study settings, the operators' options, the
    preferences and the volume's node group show its defaults and ranges (issue 13)."""
    import bpy

    name = pdehead_ext.__name__
    D = sys.modules[name + ".pdehead_addon.defaults"]
    settings = bpy.types.Object.bl_rna.properties["pdehead"].fixed_type.bl_rna.properties  # the settings Empty

    def check(props, where):
        checked = 0
        for key, p in D.PARAMS.items():
            if key not in props.keys():
                continue
            prop = props[key]
            default = tuple(prop.default_array) if getattr(prop, "is_array", False) else prop.default
            expected = p.default
            if isinstance(expected, tuple):
                assert default == pytest.approx(expected), (where, key)
            elif isinstance(expected, float):
                assert default == pytest.approx(expected), (where, key)
            else:
                assert default == expected, (where, key, default, expected)
            if p.min is not None and hasattr(prop, "hard_min"):
                assert prop.hard_min == pytest.approx(p.min), (where, key)
            if p.max is not None and hasattr(prop, "hard_max"):
                assert prop.hard_max == pytest.approx(p.max), (where, key)
            checked += 1
        return checked

    assert check(settings, "study settings") == 38  # every study setting of the table (33 + the bone level pair
    #                                                 + the CT detail map's toggle, strength and size)
    for op, at_least in (("run_pipeline", 6), ("extract_boundaries", 7), ("reconstruct_surface", 10),
                         ("build_solid", 6), ("build_volume", 8), ("import_ct", 4)):
        rna = getattr(bpy.ops.pdehead, op).get_rna_type().properties
        assert check(rna, op) >= at_least, op
    # Import CT's voxel size is named apart from the study's measured spacing; its dtype list is the table's
    imp = bpy.ops.pdehead.import_ct.get_rna_type().properties
    assert tuple(imp["spacing"].default_array) == pytest.approx(D.IMPORT_SPACING.default)
    assert imp["spacing"].hard_min == pytest.approx(D.IMPORT_SPACING.min)
    assert tuple(i.identifier for i in imp["raw_dtype"].enum_items) == D.RAW_DTYPE.choices
    assert tuple(i.identifier for i in imp["byte_order"].enum_items) == D.BYTE_ORDER.choices
    prefs = bpy.context.preferences.addons[name].preferences.bl_rna.properties["default_patches"]
    assert (prefs.default, prefs.hard_min, prefs.hard_max) == (D.PATCHES.default, D.PATCHES.min, D.PATCHES.max)
    volume_material = sys.modules[name + ".operators.volume.material"]
    group = volume_material.ensure_eq24_group()
    sockets = {s.name: s for s in group.interface.items_tree if getattr(s, "in_out", "") == "INPUT"}
    assert sockets["Density"].default_value == pytest.approx(D.DENSITY.default) == pytest.approx(40.0)
    assert sockets["W"].default_value == pytest.approx(sys.modules[name + ".pdehead_addon"].OUTSIDE_W)



def _rna_summary(prop) -> dict:
    """What a property shows and accepts (everything but its live update): type, label, tooltip, subtype,
    unit, default, range, enumeration items, animatable."""
    out = {"type": prop.type, "name": prop.name, "description": prop.description, "subtype": prop.subtype,
           "animatable": prop.is_animatable}
    if prop.type in ("INT", "FLOAT", "BOOLEAN"):
        out["default"] = tuple(prop.default_array) if prop.array_length else prop.default
    if prop.type in ("INT", "FLOAT"):
        out.update(range=(prop.hard_min, prop.hard_max, prop.soft_min, prop.soft_max))
    if prop.type == "FLOAT":
        out.update(unit=prop.unit, precision=prop.precision)
    if prop.type == "ENUM":
        out.update(default=prop.default, items=[(i.identifier, i.name, i.description) for i in prop.enum_items])
    return out


def test_every_operator_option_of_a_study_setting_is_that_setting(pdehead_ext):
    """Each study setting is declared once (operators/study/props.py's SETTINGS over the defaults table): an
    operator's option of the same name shows and accepts exactly what the sidebar's setting does, and every
    setting of the table is on the study's settings (animatable, as before)."""
    import bpy

    name = pdehead_ext.__name__
    props = sys.modules[name + ".operators.study.props"]
    D = sys.modules[name + ".pdehead_addon.defaults"]
    settings = bpy.types.Object.bl_rna.properties["pdehead"].fixed_type.bl_rna.properties
    assert set(props.SETTINGS) <= set(settings.keys()) and set(props.SETTINGS) <= set(D.PARAMS)
    assert all(settings[key].is_animatable for key in props.SETTINGS)
    offered = {"extract_boundaries": 7, "reconstruct_surface": 10, "build_solid": 9, "build_volume": 8,
               "run_pipeline": 8, "import_ct": 2}
    for op, count in offered.items():
        rna = getattr(bpy.ops.pdehead, op).get_rna_type().properties
        shared = [key for key in props.SETTINGS if key in rna.keys()]
        assert len(shared) == count, (op, shared)
        for key in shared:
            assert _rna_summary(rna[key]) == _rna_summary(settings[key]), (op, key)
    ops = sys.modules[name + ".operators.ui.ops"]
    assert ops.PDEHEAD_OT_extract_boundaries.mirrored_settings == (
        "patches", "samples", "selection", "align_curves", "use_tolerance", "tolerance_mm", "max_tolerance_mm")
    assert not hasattr(ops.PDEHEAD_OT_run_pipeline, "mirrored_settings")  # its options start a new run


def test_shipped_wheels_import_from_the_extension_site_packages(pdehead_ext):
    """skimage, scipy, pydicom and its decoders import from the wheels Blender unpacked (not from this machine's site).

    The decoders (built against numpy 2's backward-compatible ABI) must also decode on the
    numpy 1.26 of Blender 4.2 - 5.0: JPEG 2000 and JPEG-LS lossless files give exactly the
    uncompressed pixels, and a baseline JPEG decodes to its RGB shape.
    """
    import bpy
    # where Blender unpacks extension wheels, for the running Python (3.11 or 3.13)
    site = (Path(bpy.utils.user_resource('EXTENSIONS')) / ".local" / "lib"
            / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages")
    assert (site / "skimage").is_dir() and (site / "pydicom").is_dir() and (site / "scipy").is_dir()
    assert (site / "pylibjpeg").is_dir() and (site / "openjpeg").is_dir() and (site / "libjpeg").is_dir()
    assert not (site / "numpy").exists()  # Blender's own numpy is used
    assert str(site) in sys.path
    code = (
        "import sys, os; sys.path.insert(0, sys.argv[1]);"
        "import numpy as np, skimage, scipy, pydicom, pylibjpeg, openjpeg, libjpeg;"
        "from skimage import measure; from scipy import ndimage;"
        "mods = (skimage, scipy, pydicom, pylibjpeg, openjpeg, libjpeg);"
        "assert all(m.__file__.startswith(sys.argv[1]) for m in mods), [m.__file__ for m in mods];"
        "a = np.zeros((32, 32)); a[8:24, 8:24] = 1;"
        "c = measure.find_contours(ndimage.gaussian_filter(a, 1.0), 0.5);"
        "d = os.path.join(os.path.dirname(pydicom.__file__), 'data', 'test_files');"
        "read = lambda n: pydicom.dcmread(os.path.join(d, n));"
        "ref = read('MR_small.dcm').pixel_array;"
        "same = [bool(np.array_equal(read(n).pixel_array, ref)) for n in "
        "('MR_small_jp2klossless.dcm', 'MR_small_jpeg_ls_lossless.dcm')];"
        "rgb = read('SC_rgb_jpeg_dcmtk.dcm').pixel_array;"
        "print(len(c), skimage.__version__, scipy.__version__, pydicom.__version__, openjpeg.__version__,"
        " libjpeg.__version__, same[0], same[1], 'x'.join(map(str, rgb.shape)), np.__version__)"
    )
    out = subprocess.run([sys.executable, "-c", code, str(site)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    n, skv, spv, pdv, ojv, ljv, j2k, jls, rgb, npv = out.stdout.split()
    pins = build_extension.read_pins()
    assert (int(n), skv, spv, pdv) == (1, pins["scikit-image"], pins["scipy"], pins["pydicom"])
    assert (ojv, ljv) == (pins["pylibjpeg-openjpeg"], pins["pylibjpeg-libjpeg"])
    assert (j2k, jls, rgb) == ("True", "True", "100x100x3"), npv


def _our_handlers(prefix: str) -> list[str]:
    import bpy
    found = []
    for name in dir(bpy.app.handlers):
        handlers = getattr(bpy.app.handlers, name)
        if isinstance(handlers, list):
            found += [f"{name}:{h.__name__}" for h in handlers if getattr(h, "__module__", "").startswith(prefix)]
    return found


def test_unregister_leaves_nothing_and_register_again_works(pdehead_ext):
    import addon_utils
    import bpy
    name = pdehead_ext.__name__
    assert sorted(_our_handlers(name)) == OUR_HANDLERS
    def menu_funcs():
        return [f.__module__ for f in getattr(bpy.types.TOPBAR_MT_file_import.draw, "_draw_funcs", [])]
    assert name + ".operators.ui.ops" in menu_funcs()

    addon_utils.disable(name, default_set=True)
    try:
        assert name not in bpy.context.preferences.addons
        assert dir(bpy.ops.pdehead) == []
        for cls_name in ["PDEHEAD_OT_" + op for op in OPERATORS] + PANELS + [
                "PDEHeadStudySettings", "PDEHeadSceneSettings", "PDEHeadPreferences"]:
            assert not hasattr(bpy.types, cls_name), cls_name
        assert not hasattr(bpy.types.Collection, "pdehead")
        assert not hasattr(bpy.types.Collection, "pdehead_settings_object")
        assert not hasattr(bpy.types.Object, "pdehead")
        assert not hasattr(bpy.types.Scene, "pdehead")
        assert not hasattr(bpy.types, "PDEHEAD_FH_import_ct")
        assert _our_handlers(name) == []
        assert name + ".operators.ui.ops" not in menu_funcs()
        # no bpy.app timer of ours (the modal pipeline uses a window-manager timer owned by the operator)
        ops_mod = sys.modules[name + ".operators.ui.ops"]
        assert not any(bpy.app.timers.is_registered(f) for f in vars(ops_mod).values() if callable(f)
                       and getattr(f, "__module__", "") == ops_mod.__name__)
    finally:
        addon_utils.enable(name, default_set=True)
    assert set(OPERATORS) <= set(dir(bpy.ops.pdehead))
    assert sorted(_our_handlers(name)) == OUR_HANDLERS
    assert hasattr(bpy.types.Collection, "pdehead")
    # a second cycle, and the add-on still works afterwards
    addon_utils.disable(name, default_set=True)
    addon_utils.enable(name, default_set=True)
    assert bpy.ops.pdehead.load_phantom() == {'FINISHED'}
    assert len(_our_handlers(name)) == len(OUR_HANDLERS)


def test_dev_shim_registers_from_source(tmp_path):
    """The CLI's way: the repo loaded as package 'pdehead_dev' without a zip (own Blender process)."""
    code = f"""
import importlib.util, sys
from pathlib import Path
import bpy
root = Path({str(ROOT)!r})
spec = importlib.util.spec_from_file_location("pdehead_dev", root / "__init__.py",
                                              submodule_search_locations=[str(root)])
mod = importlib.util.module_from_spec(spec); sys.modules["pdehead_dev"] = mod; spec.loader.exec_module(mod)
mod.register()
assert "run_pipeline" in dir(bpy.ops.pdehead)
mod.unregister()
assert dir(bpy.ops.pdehead) == []
mod.register()
mod.operators.compat.unregister_at_exit(mod.unregister)  # bpy 4.2 / 4.5 crash / hang at exit otherwise
print("ok")
"""
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr
