"""What the scripts share: the data sets and how each is loaded, the paper's numbers, timing, the dev shim.

One owner for each, so the benchmarks, the figure scripts and the CLI cannot drift apart:

- :data:`SHARED_DATA` and the loader options of the real data sets (``tests/datasets.py`` reads
  them from here: scripts never import from ``tests/``);
- :data:`PAPER`: the paper's measured numbers the benchmarks compare with;
- :func:`timed`: median / min / all wall times of a call;
- :func:`load_addon`: the add-on loaded from this repository as package ``pdehead_dev`` (no zip);
- :func:`defaults`: the one table of user-facing defaults (``pdehead_addon/defaults.py``);
- for the benchmarks and figure scripts (``scripts/bench/``): the data sets' segmentation, the
  marching-cubes peer, the tube fidelity, the boundaries at the add-on's defaults, and the Blender
  layer loaded once (:func:`blender`, :func:`remove_object`).

Scripts put ``scripts/`` on ``sys.path`` (Python does that for a script run from ``scripts/``; the
benchmarks and figure scripts in ``scripts/bench/`` insert it themselves) and ``import _common``. It
stays in ``scripts/``, not ``scripts/bench/``: the CLI (``pdehead.py``, ``pdehead_batch.py``),
``input_cases.py`` and the tests use it too.
"""
from __future__ import annotations

import gc
import importlib
import importlib.util
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Callable

import _cli_flags
from _cli_flags import defaults  # noqa: F401  (the one table of defaults, re-exported for the scripts)

ROOT = Path(__file__).resolve().parents[1]
#: Real data is read in place from ``../shared/data`` (override with ``PDEHEAD_DATA``), never copied.
SHARED_DATA = Path(os.environ.get("PDEHEAD_DATA", ROOT.parent / "shared" / "data"))

#: How each real data set is loaded (``load_ct`` keyword arguments).
CTHEAD_RAW16_OPTIONS = dict(format="raw", shape=(256, 256), dtype=">i2", spacing=(2.0, 1.0, 1.0),
                            first_slice="superior")
CTHEAD_TIFF8_OPTIONS = dict(spacing=(2.0, 1.0, 1.0), first_slice="superior")

#: The paper's numbers (CThead, 99 slices): storage of its boundary file and of marching cubes, the
#: PDE and marching-cubes times, the boundary extraction time and the mean Jaccard of its segmentation.
PAPER = {"storage_ours_kB": 62, "storage_mc_kB": 37647, "pde_seconds": 0.66, "mc_seconds": 874.75,
         "boundary_seconds": 14.23, "jaccard_mean": 0.9815}


def addon_import_options(name: str) -> dict:
    """``bpy.ops.pdehead.import_ct`` keyword arguments of a real data set ("cthead": the raw16 slices, "ge":
    the tilted DICOM series): the add-on's dialog filled in as a user would (one copy for the Blender scripts)."""
    if name == "cthead":
        o = CTHEAD_RAW16_OPTIONS
        return dict(directory=str(data_path("cthead_stanford", "raw16")), format='RAW', raw_shape=o["shape"],
                    raw_dtype="i2", byte_order='BIG', use_spacing=True, spacing=o["spacing"],
                    first_slice='SUPERIOR')
    if name == "ge":
        return dict(directory=str(data_path("ct_head_ge_tilt_dicom", "dicom")))
    raise SystemExit(f"unknown dataset {name!r} (cthead, ge)")


def data_path(*parts: str) -> Path:
    """A path inside :data:`SHARED_DATA`; a clear error naming it when it is not there."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        raise FileNotFoundError(f"real data not found: {path} (set PDEHEAD_DATA to the shared data folder)")
    return path


def load_note(load, cores) -> str:
    """How busy the machine was, for a benchmark's heading: 'quiet' when the 1-minute load average at the
    start was below the core count (the benchmark's own processes come after), else shared."""
    if not load:
        return "load not recorded"
    if load[0] < (cores or 1):
        return "the machine otherwise quiet"
    return "**the machine was shared with other jobs**: the wall clock is inflated, CPU time much less"


def median(xs) -> float:
    return float(statistics.median(xs)) if xs else float("nan")


def timed(fn: Callable[[], Any], repeats: int, before: Callable[[], Any] | None = None, warmup: bool = False):
    """Run ``fn`` ``repeats`` times; (stats dict, last result). ``before`` runs untimed before each.

    ``warmup``: one untimed call first (one-time costs such as lazy imports and first-touch
    allocations; used for the millisecond stages, for ours and the peer alike). The stats are
    ``median_s``, ``min_s`` and ``runs_s``.
    """
    runs, result = [], None
    if warmup:
        result = fn()
    gc.collect()  # once: a full collection costs ~0.1 s here, longer than many of the timed calls
    for _ in range(max(1, int(repeats))):
        if before is not None:
            before()
        gc.disable()  # like timeit: no collector pauses inside the timed call
        try:
            t0 = time.perf_counter()
            result = fn()
            runs.append(time.perf_counter() - t0)
        finally:
            gc.enable()
    return {"median_s": median(runs), "min_s": float(min(runs)), "runs_s": [float(r) for r in runs]}, result


DEV_PACKAGE = "pdehead_dev"


def load_addon(register: bool = False, engine=None):
    """The add-on's root package loaded from this repository as ``pdehead_dev`` (the dev shim, no zip).

    Parameters
    ----------
    register : bool
        Also register it (operators, properties, handlers) and unregister it at interpreter exit
        (the bpy 4.2 / 4.5 modules crash / hang at exit with add-on classes still registered).
    engine : module, optional
        An already imported ``pdehead_addon`` to reuse as ``pdehead_dev.pdehead_addon`` (one copy of
        the engine in the process, so its types are shared with the caller's).
    """
    import bpy  # noqa: F401  (bpy first: the add-on imports it)
    if engine is not None:
        for name, mod in list(sys.modules.items()):  # the package and its subpackages (the packaged layout)
            if name == engine.__name__ or name.startswith(engine.__name__ + "."):
                sys.modules.setdefault(f"{DEV_PACKAGE}.pdehead_addon{name[len(engine.__name__):]}", mod)
    module = sys.modules.get(DEV_PACKAGE)
    if module is None:
        spec = importlib.util.spec_from_file_location(DEV_PACKAGE, ROOT / "__init__.py",
                                                      submodule_search_locations=[str(ROOT)])
        module = importlib.util.module_from_spec(spec)
        sys.modules[DEV_PACKAGE] = module
        spec.loader.exec_module(module)
    if register and not getattr(module, "_pdehead_dev_registered", False):
        module.register()
        module._pdehead_dev_registered = True
        importlib.import_module(f"{DEV_PACKAGE}.operators.compat").unregister_at_exit(module.unregister)
    return module


# ----------------------------------------------------------------------------- the benchmarks' data and peer
def load_segmentation(name: str):
    """``segment_head`` of a benchmark data set: "cthead" (raw16), "ge" (the tilted DICOM series) or the phantom."""
    import pdehead_addon as E
    if name == "cthead":
        ct = E.load_ct(SHARED_DATA / "cthead_stanford" / "raw16", **CTHEAD_RAW16_OPTIONS)
    elif name == "ge":
        ct = E.load_ct(SHARED_DATA / "ct_head_ge_tilt_dicom" / "dicom")
    else:
        ct = E.make_phantom().ct
    return E.segment_head(ct)


def marching_cubes(seg):
    """The peer: skimage's marching cubes of the mask at 0.5, vertices in patient mm, and its triangles."""
    return marching_cubes_arrays(seg.mask, seg.ct)


def marching_cubes_arrays(mask, ct):
    """Marching cubes (skimage, level 0.5, whole mask): vertices in patient mm and the triangles."""
    import numpy as np
    from skimage import measure
    verts, faces, _, _ = measure.marching_cubes(mask.astype(np.float32, copy=False), 0.5)
    return ct.index_to_patient(verts), faces


def marching_cubes_mesh(mask, ct):
    """The peer mesh: :func:`marching_cubes_arrays` as an engine ``Mesh`` (LPS mm, triangles only)."""
    import numpy as np

    import pdehead_addon as E
    verts, faces = marching_cubes_arrays(mask, ct)
    return E.Mesh(vertices=verts, quads=np.zeros((0, 4), np.int64), triangles=np.asarray(faces, np.int64))


def boundaries(seg, patches: int | None = None, samples: int | None = None, selection: str | None = None):
    """Boundary curves as the add-on makes them by default (``pdehead_addon/defaults.py``: its default
    slice selection, patches and samples; the angular samples around a smooth spine)."""
    import pdehead_addon as E
    D = defaults()
    return E.extract_boundaries(seg, patches=D.PATCHES.default if patches is None else patches,
                                samples=D.SAMPLES.default if samples is None else samples,
                                selection=D.SELECTION.default if selection is None else selection)


def error_text(exc: BaseException) -> str:
    """A failed step's one-line text for a report ("not available (...)" for a missing package)."""
    if isinstance(exc, ImportError):
        return f"not available ({exc})"
    return f"{type(exc).__name__}: {exc}"


# ----------------------------------------------------------------------------- the Blender layer (dev shim)
_BLENDER: dict | None = None


def blender() -> dict:
    """bpy and the add-on's operators.scene.objects/volume/render, loaded from this repo (:func:`load_addon`,
    sharing the already imported engine ``pdehead_addon``); loaded once per process."""
    global _BLENDER
    if _BLENDER is None:
        import tempfile
        os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="pdehead-bench-blender-"))
        t0 = time.perf_counter()
        import bpy

        import pdehead_addon as E
        # one copy of the engine: the add-on's relative imports resolve to the module already loaded
        load_addon(engine=E)
        mods = {name: importlib.import_module(f"{DEV_PACKAGE}.operators.{path}")
                for name, path in (("objects", "scene.objects"), ("volume", "volume.volume"),
                                   ("vdb_grids", "volume.vdb_grids"), ("volume_material", "volume.material"),
                                   ("render", "scene.render"), ("detail_map", "scene.detail_map"))}
        _BLENDER = {"bpy": bpy, **mods, "import_s": time.perf_counter() - t0, "version": bpy.app.version_string}
    return _BLENDER


def remove_object(obj) -> None:
    """Remove a Blender object and its mesh / volume data when nothing else uses it."""
    bpy = blender()["bpy"]
    data = obj.data
    bpy.data.objects.remove(obj)
    if data is not None and data.users == 0:
        if isinstance(data, bpy.types.Mesh):
            bpy.data.meshes.remove(data)
        elif isinstance(data, bpy.types.Volume):
            bpy.data.volumes.remove(data)


def tube_fidelity(head, verts, faces, samples: int, everything: bool = False) -> dict:
    """Symmetric distance of the open tube (8t+1 rows x 256 between the lowest and the highest curve:
    not the crown's dome above it) to the MC triangles in the curves' z range: mean, p95, max (and,
    with ``everything``, all that ``symmetric_surface_distance`` returns)."""
    import numpy as np

    import pdehead_addon as E
    from pdehead_addon.pde.surface_mesh import tube_mesh
    z = head.bset.curves[..., 2]
    cz = verts[faces][:, :, 2].mean(axis=1)
    sel = faces[(cz >= z.min()) & (cz <= z.max())]
    u = np.linspace(head.curve_u[0], head.curve_u[-1], 8 * head.patches + 1)
    tube = tube_mesh(head.surface_points(u, 256), head.orientation)
    d = E.validation.symmetric_surface_distance(tube.vertices, tube.quads, verts, sel, samples=samples)
    return d if everything else {k: float(d[k]) for k in ("mean", "p95", "max")}


# --------------------------------------------------------------------------- the command lines' loader options
#: The loader flags of ``pdehead.py`` and ``pdehead_batch.py run`` (argparse destinations).
LOADER_FLAGS = ("format", "raw_shape", "dtype", "spacing", "first_slice", "orientation", "units", "series_uid",
                "downsample")


def add_loader_arguments(parser):
    """The loader options group (``--format`` ... ``--downsample``): one definition for both command lines,
    so a single CT and a batch of them are read the same way. Returns the group."""
    D = defaults()
    g = parser.add_argument_group("loader options")
    g.add_argument("--format", default="auto", choices=["auto", "dicom", "images", "raw"])
    g.add_argument("--raw-shape", type=int, nargs=2, metavar=("NY", "NX"), help="raw slices: rows, columns")
    g.add_argument("--dtype", help="raw data type, numpy style: '>i2' (big-endian int16), '<u2', 'u1', '<f4'")
    g.add_argument("--spacing", type=float, nargs=3, metavar=("DZ", "DY", "DX"), help="voxel size in mm")
    g.add_argument("--first-slice", choices=list(D.FIRST_SLICE_CHOICES),
                   help="raw/image stacks: where the first file lies; default auto: inferior, unless the head's "
                        "crown (where it closes) is at the first file, then superior (said as information)")
    g.add_argument("--orientation", metavar="CODE",
                   help="raw/image stacks: 3 letters for the directions in which the column, row and file "
                        "index increase, e.g. LPS (default), LAS (row 0 = back of the head), RAS, PIL")
    g.add_argument("--units", choices=["HU", "stored"],
                   help="raw/image stacks and NIfTI: the samples are HU, or stored values (the default for them)")
    g.add_argument("--series-uid", help="DICOM SeriesInstanceUID when the folder holds several series")
    _cli_flags.add(g, "downsample")      # a study setting: its flag generated from the defaults table
    return g


def check_loader_args(error, args) -> None:
    """The loader options together: raw input needs its shape, type and spacing (``--raw-shape`` or ``--dtype``
    alone say raw), ``--orientation`` excludes ``--first-slice`` (``--downsample``'s range: :func:`_cli_flags.check`).
    ``error(message)`` reports a usage error (it must not return)."""
    if args.raw_shape or args.dtype:
        args.format = "raw"
    if args.format == "raw" and not (args.raw_shape and args.dtype and args.spacing):
        error("raw input needs --raw-shape NY NX, --dtype and --spacing DZ DY DX")
    if args.orientation and args.first_slice not in (None, "auto"):
        error("give either --orientation or --first-slice (the orientation's third letter says where the files go)")


def engine_loader_options(args) -> dict:
    """``load_ct`` keyword arguments of the loader options (``pdehead_batch.py``'s workers run the engine
    without Blender; ``pdehead.py`` fills the add-on's import dialog instead). Only what was given; JSON-able."""
    options: dict = {}
    if args.format != "auto":
        options["format"] = args.format
    if args.format == "raw":
        options.update(shape=list(args.raw_shape), dtype=args.dtype)
    if args.spacing:
        options["spacing"] = list(args.spacing)
    if args.first_slice and args.first_slice != "auto":
        options["first_slice"] = args.first_slice
    if args.orientation:
        options["orientation"] = args.orientation.upper()
    if args.units:
        options["units"] = args.units
    if args.series_uid:
        options["series_uid"] = args.series_uid
    if args.downsample > 1:
        options["downsample"] = int(args.downsample)
    return options
