"""Real-Blender test set-up: the BUILT extension zip installed into a temporary user folder.

- ``extension_zip`` (session): the linux-x64 zip named by ``PDEHEAD_EXTENSION_ZIP`` (``.ci/run`` builds the
  zips once and every Blender leg installs the same one), else ``scripts/build_extension.py --platform
  linux-x64`` into a temp folder.
- ``pdehead_ext`` (session): that zip installed and enabled offline with
  ``bpy.ops.extensions.package_install_files`` into ``BLENDER_USER_RESOURCES`` (a temp folder set by
  tests/conftest.py before bpy is imported); returns the module ``bl_ext.user_default.pdehead``.
- ``ext``: handles on the installed extension's modules: ``ext.engine`` (its ``pdehead_addon``) and every
  module of its Blender layer by dotted name (``ext.ui.ops``, ``ext.state``, ``ext.study.entity``, ...);
  the one fixture the tests reach the installed code through.
- ``clean_scene`` (autouse): an empty file around every test, so tests do not see each other's objects.
- ``phantom_blend`` / ``cthead_blend`` (session): the one-click pipeline run once on the phantom /
  on CThead raw16 and saved to a temp .blend; tests reopen that file instead of recomputing.
"""
from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXTENSION_MODULE = "bl_ext.user_default.pdehead"


def pytest_collection_modifyitems(config, items):
    here = Path(__file__).parent
    same_engine = os.environ.get("PDEHEAD_ENGINE_CLI") == "skip"
    for item in items:
        if here in Path(str(item.fspath)).parents:
            item.add_marker(pytest.mark.blender)
        if same_engine and item.get_closest_marker("engine_cli"):
            item.add_marker(pytest.mark.skip(reason="engine_cli: the engine's own work, run on the 5.0.1 leg with "
                                                    "the same Python and numpy (PDEHEAD_ENGINE_CLI=skip)"))


@pytest.fixture(scope="session")
def extension_zip(tmp_path_factory) -> Path:
    """The linux-x64 extension zip: $PDEHEAD_EXTENSION_ZIP, else built from the working tree (once per session)."""
    given = os.environ.get("PDEHEAD_EXTENSION_ZIP")
    if given:
        assert Path(given).is_file(), f"PDEHEAD_EXTENSION_ZIP={given}: no such file"
        assert Path(given).name == "pdehead-0.1.0-linux_x64.zip", given
        return Path(given)
    out = tmp_path_factory.mktemp("pdehead-dist")
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "build_extension.py"),
                             "--platform", "linux-x64", "--output-dir", str(out)],
                            capture_output=True, text=True)
    assert result.returncode == 0, f"extension build failed:\n{result.stdout}\n{result.stderr}"
    zips = sorted(out.glob("*.zip"))
    assert [z.name for z in zips] == ["pdehead-0.1.0-linux_x64.zip"], result.stdout
    return zips[0]


@pytest.fixture(scope="session")
def pdehead_ext(extension_zip):
    """The extension installed from the zip into the temporary user folder and enabled."""
    import bpy
    user = os.environ.get("BLENDER_USER_RESOURCES", "")
    assert user and Path(bpy.utils.user_resource('EXTENSIONS')).is_relative_to(user), \
        "BLENDER_USER_RESOURCES must point to a temporary folder before bpy is imported"
    result = bpy.ops.extensions.package_install_files(filepath=str(extension_zip), repo='user_default',
                                                      enable_on_install=True)
    assert result == {'FINISHED'}
    assert EXTENSION_MODULE in bpy.context.preferences.addons
    module = importlib.import_module(EXTENSION_MODULE)
    import addon_utils
    # the bpy 4.2 / 4.5 modules crash / hang at exit with add-on classes still registered
    module.operators.compat.unregister_at_exit(lambda: addon_utils.disable(EXTENSION_MODULE, default_set=False))
    return module


@pytest.fixture(autouse=True)
def clean_scene():
    """An empty file before and after each test (add-ons stay enabled)."""
    import bpy
    bpy.ops.wm.read_homefile(use_empty=True)
    yield
    bpy.ops.wm.read_homefile(use_empty=True)


def root_conftest(config):
    """The tests/conftest.py module (shared_data, CTHEAD_RAW16_OPTIONS, ...), as pytest loaded it."""
    target = (ROOT / "tests" / "conftest.py").resolve()
    for plugin in config.pluginmanager.get_plugins():
        file = getattr(plugin, "__file__", None)
        if file and Path(file).resolve() == target:
            return plugin
    raise RuntimeError("tests/conftest.py is not loaded")


def study_summary(coll) -> dict:
    """name -> (type, vertex count) of the objects of a study collection."""
    out = {}
    for obj in coll.all_objects:
        n = len(obj.data.vertices) if obj.type == 'MESH' else None
        out[obj.name] = (obj.type, n)
    return out


def _run_and_save(pdehead_ext, tmp_path_factory, name: str, run) -> Path:
    import bpy
    bpy.ops.wm.read_homefile(use_empty=True)
    folder = tmp_path_factory.mktemp(name)
    blend = folder / f"{name}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))  # saved first: the VDB goes beside it
    run(bpy)
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.read_homefile(use_empty=True)
    return blend


@pytest.fixture(scope="session")
def phantom_blend(pdehead_ext, tmp_path_factory) -> Path:
    """A saved .blend with the whole pipeline run on the phantom (t=6, 32x48, nw=4, 4 mm voxels)."""
    def run(bpy):
        bpy.ops.pdehead.run_pipeline(source='PHANTOM', patches=6, nu=32, nv=48, nw=4, voxel_size=4.0)
    return _run_and_save(pdehead_ext, tmp_path_factory, "phantom", run)


@pytest.fixture(scope="session")
def cthead_blend(pdehead_ext, tmp_path_factory, pytestconfig) -> Path:
    """A saved .blend with every operator run step by step on CThead raw16 (t=10)."""
    top = root_conftest(pytestconfig)
    folder = top.shared_data("cthead_stanford", "raw16")
    o = top.CTHEAD_RAW16_OPTIONS

    def run(bpy):
        bpy.ops.pdehead.import_ct(directory=str(folder), format='RAW', raw_shape=o["shape"], raw_dtype="i2",
                                  byte_order='BIG', spacing=o["spacing"], first_slice='SUPERIOR')
        bpy.ops.pdehead.segment()
        bpy.ops.pdehead.extract_boundaries(patches=10, samples=256)
        bpy.ops.pdehead.reconstruct_surface(nu=40, nv=60)
        bpy.ops.pdehead.build_solid(nu=40, nv=60, nw=5)
        bpy.ops.pdehead.build_volume(voxel_size=3.0)
    return _run_and_save(pdehead_ext, tmp_path_factory, "cthead", run)


@pytest.fixture()
def ext(pdehead_ext):
    """The installed extension's modules: ``engine`` (its pdehead_addon) and every ``operators`` subpackage and
    top-level module by name, each subpackage with its modules (``ext.state``, ``ext.scene.objects``)."""
    import pkgutil
    from types import SimpleNamespace
    ops = pdehead_ext.operators
    for m in pkgutil.walk_packages(ops.__path__, prefix=f"{ops.__name__}."):
        importlib.import_module(m.name)                 # each subpackage then holds its modules as attributes
    layer = {m.name: getattr(ops, m.name) for m in pkgutil.iter_modules(ops.__path__)}
    return SimpleNamespace(engine=importlib.import_module(f"{pdehead_ext.__name__}.pdehead_addon"), **layer)


@pytest.fixture(scope="session")
def phantom_head(phantom_seg):
    """The engine's PDE head of the phantom (t = 10, M = 128)."""
    from pdehead_addon import extract_boundaries, solve_pde
    return solve_pde(extract_boundaries(phantom_seg, patches=10, samples=128))
