"""Shared test set-up: paths to the real CTs in ../shared/data and cached pipeline results.

Real data is read in place (never copied). Locally a missing data set skips the test;
in CI (CI=true) it fails, because the real-data tests must run there.
"""
from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# Keep Blender away from the real user folder; must happen before any `import bpy`. The folder holds the
# installed extension (~300 MB with its wheels): removed when the session ends, or every run leaves one behind.
if "BLENDER_USER_RESOURCES" not in os.environ:
    os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="pdehead-blender-user-")
    atexit.register(shutil.rmtree, os.environ["BLENDER_USER_RESOURCES"], ignore_errors=True)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from datasets import CTHEAD_RAW16_OPTIONS, CTHEAD_TIFF8_OPTIONS, IN_CI, SHARED_DATA, shared_data  # noqa: E402,F401
from engine_legs import checked_leg, runs_on  # noqa: E402


def _engine_leg() -> str | None:
    try:
        return checked_leg(os.environ.get("PDEHEAD_ENGINE_LEG"))
    except ValueError as error:
        raise pytest.UsageError(str(error)) from None


def pytest_report_header(config):
    leg = _engine_leg()
    if leg:
        return (f"engine leg {leg}: the real-head engine modules tests/engine_legs.py gives the other engine leg "
                "are deselected here (PDEHEAD_ENGINE_LEG)")
    return None


def pytest_collection_modifyitems(config, items):
    """On one of .ci/run's two engine legs, leave out the modules ``tests/engine_legs.py`` gives the other."""
    leg = _engine_leg()
    if leg is None:
        return
    keep, other = [], []
    for item in items:
        module = Path(str(item.fspath)).resolve().relative_to(ROOT).as_posix()
        (keep if runs_on(module, leg) else other).append(item)
    if other:
        config.hook.pytest_deselected(items=other)
        items[:] = keep


@pytest.fixture(scope="session")
def bench_face():
    """``scripts/bench/bench_face.py``, imported once: its variants of a scan (stripped, resliced, cut, in HU), the
    unseen-like row's constants and the face scorer, as the suite makes them."""
    bench = str(ROOT / "scripts" / "bench")
    if bench not in sys.path:
        sys.path.insert(0, bench)
    import bench_face
    return bench_face


@pytest.fixture(scope="session")
def cthead_ct():
    from pdehead_addon import load_ct
    return load_ct(shared_data("cthead_stanford", "raw16"), **CTHEAD_RAW16_OPTIONS)


@pytest.fixture(scope="session")
def cthead_tiff_ct():
    from pdehead_addon import load_ct
    return load_ct(shared_data("cthead_stanford", "tiff8"), **CTHEAD_TIFF8_OPTIONS)


@pytest.fixture(scope="session")
def ge_ct():
    from pdehead_addon import load_ct
    return load_ct(shared_data("ct_head_ge_tilt_dicom", "dicom"))


@pytest.fixture(scope="session")
def phantom():
    from pdehead_addon import make_phantom
    return make_phantom()


@pytest.fixture(scope="session")
def cthead_seg(cthead_ct):
    from pdehead_addon import segment_head
    return segment_head(cthead_ct)


@pytest.fixture(scope="session")
def ge_seg(ge_ct):
    from pdehead_addon import segment_head
    return segment_head(ge_ct)


@pytest.fixture(scope="session")
def phantom_seg(phantom):
    from pdehead_addon import segment_head
    return segment_head(phantom.ct)


@pytest.fixture(scope="session")
def cthead_bset(cthead_seg):
    from pdehead_addon import extract_boundaries
    return extract_boundaries(cthead_seg, patches=10, samples=256)


@pytest.fixture(scope="session")
def cthead_skull(cthead_seg, cthead_ct):
    """CThead's skull at its own bone level (the same with or without the head segmentation). Shared by several
    modules: read it, never change it."""
    from pdehead_addon.forensic.skull import segment_skull
    return segment_skull(cthead_ct, cthead_seg)


@pytest.fixture(scope="session")
def cthead_search(cthead_ct, cthead_skull):
    """find_landmarks on CThead's skull (the default search, ~25 s): read only, as ``cthead_skull``."""
    from pdehead_addon.forensic.auto_landmarks import find_landmarks
    return find_landmarks(cthead_ct, cthead_skull.bone)


@pytest.fixture(scope="session")
def phantom_skull(phantom, phantom_seg):
    """The phantom's skull (read only, as ``cthead_skull``)."""
    from pdehead_addon.forensic.skull import segment_skull
    return segment_skull(phantom.ct, phantom_seg)


@pytest.fixture(scope="session")
def phantom_search(phantom, phantom_skull):
    """find_landmarks on the phantom's skull (read only)."""
    from pdehead_addon.forensic.auto_landmarks import find_landmarks
    return find_landmarks(phantom.ct, phantom_skull.bone)


@pytest.fixture(scope="session")
def phantom_skull_mesh(phantom_skull):
    """The phantom skull's mesh (read only)."""
    from pdehead_addon.forensic.skull import skull_mesh
    return skull_mesh(phantom_skull)
