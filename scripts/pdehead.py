#!/usr/bin/env python3
"""PDE Head from the command line: CT slices -> .blend with the PDE head (and renders), headless.

Examples::

    python3 scripts/pdehead.py --phantom --out demo/phantom.blend --render demo/surface.png
    python3 scripts/pdehead.py ../shared/data/cthead_stanford/raw16 --raw-shape 256 256 --dtype '>i2' \\
        --spacing 2 1 1 --first-slice superior --patches 10 --out out/cthead.blend \\
        --render out/cthead_surface.png --render-volume out/cthead_volume.png
    python3 scripts/pdehead.py ../shared/data/ct_head_ge_tilt_dicom/dicom --out out/ge.blend
    python3 scripts/pdehead.py --phantom --no-volume --skull --export out/print
        # -> skull.stl, skull_envelope.stl, skin.stl, ...
    python3 scripts/pdehead.py --phantom --no-volume --out out/turn.blend --turntable 120 --render-animation out/turn

It runs the SAME steps as the add-on in the ``bpy`` module: the study's methods that the add-on's operators
call (import, segment, boundaries, surface, CT detail, solid, volume, skull, tissue depth, landmarks, export,
turntable), whose returned outcomes give the reports it prints: the add-on is registered straight from this
repository's source (as the package ``pdehead_dev``, no zip needed), in a temporary Blender user
folder so your own Blender preferences are never touched. The .vdb of the volume is written beside the .blend
(``pdehead_vdb/``, stored as a relative path). Prints per-step timings and a summary on stdout
(``--summary-json FILE``: the same as JSON for scripts) and each warning once, as one line on stderr,
naming this command's flags. Progress of the long steps goes to stderr: a bar on a terminal, one plain
line per update when piped.
Exit status: 0 on success, 2 on bad arguments or input (a folder that is empty or holds no head CT, an
output that cannot be written: one-line error), 1 on an internal error, 130 on Ctrl-C (the running step
stops within about a second; no output file is left behind).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

import _cli_flags  # noqa: E402  (scripts/ is on sys.path: this script's folder)
import _common  # noqa: E402

ROOT = _common.ROOT
PROG = "pdehead"
#: The add-on's defaults and ranges (pdehead_addon/defaults.py): the CLI's defaults are the add-on's.
D = _common.defaults()


class CLIError(Exception):
    """A one-line error for the user; ``code`` is the exit status."""

    def __init__(self, message: str, code: int = 1):
        super().__init__(message)
        self.code = code


def parse_args(argv=None) -> argparse.Namespace:
    p = _parser()
    args = p.parse_args(argv)
    _check_skull_args(p, args)
    _check_input_args(p, args)
    _check_curve_args(p, args)
    _check_ranges(p, args)
    _check_render_args(p, args)
    check_outputs(args)
    return args


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Build a smooth PDE head in Blender from head CT slices.")
    p.add_argument("input", nargs="?", help="DICOM folder, image-stack folder, raw-slice folder or file")
    p.add_argument("--phantom", action="store_true", help="use the built-in synthetic head instead of INPUT")
    flag = _cli_flags.add                  # a study setting's flag: generated from the defaults table
    flag(p, "patches", given=True)
    flag(p, "samples")
    flag(p, "tolerance_mm")
    flag(p, "max_tolerance_mm")
    flag(p, "selection", given=True)
    flag(p, "align_curves")
    flag(p, "nu")
    flag(p, "nv")
    flag(p, "detail_strength")
    flag(p, "nw")
    flag(p, "voxel_size")
    p.add_argument("--no-volume", action="store_true", help="skip the volume (w-field + VDB)")
    p.add_argument("--out", type=Path, help="write the .blend here (the .vdb goes beside it)")
    p.add_argument("--render", type=Path, metavar="IMAGE",
                   help="render the surface (front view) to this .png or .jpg")
    p.add_argument("--render-volume", type=Path, metavar="IMAGE",
                   help="render the volume (front view) to this .png or .jpg")
    p.add_argument("--summary-json", type=Path, metavar="FILE",
                   help="also write the summary (study, counts, timings, warnings, outputs) as JSON to FILE")
    flag(p, "view")
    flag(p, "resolution")
    f = p.add_argument_group("forensic")
    f.add_argument("--skull", action="store_true",
                   help="also build the skull (PDE surface + bone mesh) and the skin's tissue-depth map")
    f.add_argument("--export", type=Path, metavar="DIR",
                   help="with --skull: write skull.stl (the bone), skull_envelope.stl (PDE), skin.stl (when the CT has "
                        "skin), tissue_depth.csv, landmarks.csv and provenance.json (patient mm) into DIR")
    flag(f, "export_format")
    flag(f, "bone_level")
    f.add_argument("--skull-mesh", type=Path, metavar="FILE",
                   help="a skull mesh (STL/PLY/OBJ in mm, e.g. a surface scan) instead of a CT; implies --skull")
    f.add_argument("--face-from-skull", action="store_true",
                   help="with --export DIR: also approximate the face from the bone skull, its landmarks and the "
                        "depth table (a PDE face through the tissue-depth pegs) and write face.<fmt> (closed, patient "
                        "mm; an approximation, not an identification); implies --skull")
    f.add_argument("--depth-table", type=Path, metavar="FILE",
                   help="with --face-from-skull: the depth table CSV (landmark,mean_mm[,sd_mm,n][,sex]); default: the "
                        "shipped T-Table 2023 (pooled)")
    f.add_argument("--sex", choices=["male", "female"],
                   help="with --face-from-skull: the depth table's rows for this sex (a table with a sex column; the "
                        "T-Table 2023 is pooled)")
    flag(p, "render_samples")
    a = p.add_argument_group("animation")
    flag(a, "turntable_frames")
    a.add_argument("--render-animation", type=Path, metavar="DIR",
                   help="with --turntable: render the frames (Cycles, --resolution, --render-samples) to "
                        "DIR/frame_0001.png ...")
    _common.add_loader_arguments(p)       # one definition, shared with pdehead_batch.py run
    return p


def _check_skull_args(p, args) -> None:
    """--skull-mesh, --face-from-skull and --bone-level (the first two imply --skull)."""
    if args.skull_mesh is not None:
        if args.input or args.phantom:
            p.error("give either INPUT, --phantom or --skull-mesh")
        if not args.skull_mesh.is_file():
            raise CLIError(f"{args.skull_mesh}: no such file", 2)
        if args.bone_level is not None:
            p.error("--bone-level applies to a CT, not to --skull-mesh")
        args.input, args.skull = str(args.skull_mesh), True
    for flag in ("depth_table", "sex"):
        if getattr(args, flag) is not None and not args.face_from_skull:
            p.error(f"--{flag.replace('_', '-')} needs --face-from-skull")
    if args.depth_table is not None and not args.depth_table.is_file():
        raise CLIError(f"--depth-table {args.depth_table}: no such file", 2)
    if args.face_from_skull:
        if args.export is None:
            p.error("--face-from-skull needs --export DIR (where face.<fmt>, skull.<fmt> and landmarks.csv go)")
        args.skull = True


def _check_input_args(p, args) -> None:
    """The defaults of --patches and --selection (and whether they were given), INPUT or --phantom, the raw
    loader's options, and the options that need another."""
    args.patches_given, args.selection_given = args.patches is not None, args.selection is not None
    args.patches = D.PATCHES.default if args.patches is None else args.patches
    args.selection = D.SELECTION.default if args.selection is None else args.selection
    if args.phantom == bool(args.input):
        p.error("give either INPUT or --phantom")
    _common.check_loader_args(p.error, args)
    if args.raw_shape and min(args.raw_shape) < 1:
        raise CLIError(f"--raw-shape must be two positive numbers of pixels (rows, columns), got "
                       f"{' '.join(map(str, args.raw_shape))}", 2)
    if args.input and not Path(args.input).exists():
        raise CLIError(f"{args.input}: no such file or folder", 2)
    if args.render_volume and args.no_volume:
        p.error("--render-volume needs the volume (drop --no-volume)")
    if args.export and not args.skull:
        p.error("--export needs --skull")


def _check_curve_args(p, args) -> None:
    """--tolerance / --max-tolerance against --patches and --selection (a tolerance selects automatically)."""
    tol = args.tolerance is not None or args.max_tolerance is not None
    if tol and args.patches_given:
        p.error("give either --patches or --tolerance (the tolerance chooses the number of curves)")
    if tol and args.selection_given and args.selection != "auto":
        p.error(f"--tolerance chooses the slices itself (selection auto), not {args.selection!r}")
    for name in ("tolerance", "max_tolerance"):
        value = getattr(args, name)
        if value is not None and not value > 0:
            p.error(f"--{name.replace('_', '-')} must be a distance > 0 mm, got {value}")
    if tol:
        args.selection = "auto"


def _check_ranges(p, args) -> None:
    """Every number in its range (:mod:`pdehead_addon.defaults`, the flags :mod:`_cli_flags` generated)."""
    _cli_flags.check(p, args, p.error)


def _check_render_args(p, args) -> None:
    """--render-animation and the renders' file names."""
    if args.render_animation is not None:
        if args.turntable is None:
            p.error("--render-animation needs --turntable N (the animation to render)")
        _check_writable_folder(args.render_animation, "--render-animation")
    for flag in ("render", "render_volume"):
        path = getattr(args, flag)
        if path is not None and path.suffix.lower() not in IMAGE_SUFFIXES:
            p.error(f"--{flag.replace('_', '-')} {path}: the file name must end in "
                    f"{', '.join(IMAGE_SUFFIXES)} (PNG or JPEG)")


#: What --render / --render-volume write (operators/scene/render.py IMAGE_FORMATS).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def _writable(path: Path, flag: str, folder: bool = False) -> None:
    """A one-line CLIError (exit 2) when ``path`` cannot be written: checked before any work is done."""
    path = Path(path)
    if path.exists() and path.is_dir() != folder:
        raise CLIError(f"{flag} {path}: {'not a folder' if folder else 'is a folder'}", 2)
    parent = path if folder and path.exists() else path.parent
    existing = parent
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise CLIError(f"{flag} {path}: cannot be written ({existing} is a file, not a folder)", 2)
    if not os.access(existing, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise CLIError(f"{flag} {path}: cannot be written (permission denied)", 2)


def check_outputs(args) -> None:
    """Every output path given can be written (else exit 2 before the work)."""
    for flag in ("out", "render", "render_volume", "summary_json"):
        if getattr(args, flag) is not None:
            _writable(getattr(args, flag), "--" + flag.replace("_", "-"))
            if args.input:                        # the .blend, its pdehead_vdb/ and the images: never into the input
                from pdehead_addon.io.export import input_folder_conflict
                why = input_folder_conflict(Path(getattr(args, flag)).resolve().parent, args.input)
                if why:
                    raise CLIError(f"--{flag.replace('_', '-')} {why}", 2)
    if args.export is not None:
        _writable(args.export, "--export", folder=True)
        if args.input:                            # before the work, not after it (the export checks it again)
            from pdehead_addon.io.export import input_folder_conflict
            why = input_folder_conflict(args.export, args.input)
            if why:
                raise CLIError(f"--export {why}", 2)


def register_addon():
    """Register the add-on from the repository source as package ``pdehead_dev`` (no zip)."""
    return _common.load_addon(register=True)


@contextlib.contextmanager
def _blender_stdout(drop=("Error:", "Warning:")):
    """Capture what Blender's C code prints on stdout (operator reports, 'Info: Saved as ...') and pass
    it on without the lines starting with ``drop`` (an ERROR report is printed once, by main; warnings once,
    on stderr, by :class:`Warnings`)."""
    sys.stdout.flush()
    saved = os.dup(1)
    with tempfile.TemporaryFile(mode="w+b") as buf:
        os.dup2(buf.fileno(), 1)
        try:
            yield
        finally:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)
            buf.seek(0)
            text = buf.read().decode("utf-8", "replace")
            kept = [line for line in text.splitlines() if line and not line.startswith(drop)]
            if kept:
                print("\n".join(kept), flush=True)


class Interrupted(Exception):
    """Ctrl-C: the run stops, the files it wrote are removed, the exit status is 130."""


#: Set by the SIGINT handler; the engine's progress callback then raises Cancelled (a second Ctrl-C
#: ends the run at once: :func:`_force_exit`).
_SIGINT = [False]

#: Seconds a step may take to stop after Ctrl-C before the run is ended without it (a render, a scan or a
#: library call that reports no progress): its private files removed, exit 130.
CTRL_C_GRACE_S = 1.0


def _force_exit() -> None:
    """End the process now, exit 130: this run's private files removed (nothing committed is touched)."""
    with _OUTPUTS_LOCK:
        for cleanup in list(_CLEANUPS):
            with contextlib.suppress(Exception):
                cleanup()
        with contextlib.suppress(Exception):
            sys.stdout.flush()
        os.write(2, f"{PROG}: cancelled (Ctrl-C); no output was written\n".encode())
        os._exit(130)


def _on_sigint(_signum, _frame):
    if _SIGINT[0]:
        _force_exit()
    _SIGINT[0] = True


class Watchdog:
    """Ctrl-C honoured within about :data:`CTRL_C_GRACE_S` even while Blender or a library runs in C.

    Python runs a signal handler only between bytecodes of the main thread, so a Cycles render or a long
    C call would hold Ctrl-C back until it ends. The C-level handler also writes the signal to a pipe
    (:func:`signal.set_wakeup_fd`); this thread reads it, gives the running step the grace time to stop
    by itself (the normal path: it raises at its next progress report and cleans up), and otherwise, or
    at a second Ctrl-C, removes this run's private files and ends the process (:func:`_force_exit`).
    """

    def __init__(self):
        self.finished = threading.Event()
        self.read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)
        self.write_fd = write_fd
        self.previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        threading.Thread(target=self._watch, name="pdehead-ctrl-c", daemon=True).start()

    def _watch(self) -> None:
        count = 0
        while True:
            try:
                data = os.read(self.read_fd, 64)
            except OSError:
                return
            count += data.count(bytes([signal.SIGINT]))
            if not data or self.finished.is_set():
                return
            if count >= 2:
                _force_exit()
            if count == 1 and not self.finished.wait(CTRL_C_GRACE_S):
                _force_exit()

    def close(self) -> None:
        self.finished.set()
        signal.set_wakeup_fd(self.previous_fd)
        for fd in (self.write_fd,):
            with contextlib.suppress(OSError):
                os.close(fd)


class Progress:
    """The engine's progress on stderr: a bar redrawn in place on a terminal, plain lines when piped.

    Installed as the add-on's progress hook (``progress.set_hook``); raises the engine's
    ``Cancelled`` after Ctrl-C so the running step stops at its next report.
    """

    #: one report per this many seconds at most; the tests that cancel at a progress line set it to 0 through
    #: PDEHEAD_PROGRESS_INTERVAL_S (on a quiet machine the phantom's steps end before half a second)
    MIN_INTERVAL_S = float(os.environ.get("PDEHEAD_PROGRESS_INTERVAL_S", "0.5"))

    def __init__(self, stream=None):
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.step, self.last, self.shown = None, 0.0, -1.0

    def __call__(self, step, fraction, message=""):
        if _SIGINT[0]:
            from pdehead_dev.pdehead_addon import Cancelled
            raise Cancelled("cancelled by Ctrl-C")
        now = time.perf_counter()
        if step != self.step:
            self.end()
            self.step, self.start, self.last, self.shown = step, now, now, -1.0
        # one report per half second at most, the first after half a second (short steps stay silent)
        if now - self.last < self.MIN_INTERVAL_S or now - self.start < self.MIN_INTERVAL_S:
            return
        self.last, self.shown = now, fraction
        text = f"{step} {100 * fraction:3.0f} %" + (f" ({message})" if message else "")
        if self.tty:
            bar = "#" * int(20 * fraction)
            self.stream.write(f"\r{PROG}: [{bar:<20}] {text}\033[K")
        else:
            self.stream.write(f"{PROG}: {text}\n")
        self.stream.flush()

    def end(self):
        if self.tty and self.shown >= 0:
            self.stream.write("\n")
            self.stream.flush()
        self.shown = -1.0


def _step(work, report=lambda result: ()):
    """Run one step of the study (a call of its methods, as its operator makes) and print the operator's INFO
    reports (``report(result)``: the lines) of the result it returns (a StepOutcome, or the study an import
    made). A failure is the CLI's one error line: exit 2 for a PDEHeadError (the engine refused the input: bad
    files, bad options), 1 for anything else (a bug: its traceback on stderr); the study's new warnings are
    printed (:class:`Warnings`). Returns the result."""
    import traceback

    addon = sys.modules[_common.DEV_PACKAGE]
    state = addon.operators.state
    try:
        with _blender_stdout():
            result = work()
            for line in report(result):
                print(f"Info: {line}")
        if _SIGINT[0]:
            raise Interrupted()
    except (Interrupted, KeyboardInterrupt):
        raise
    except Exception as exc:  # noqa: BLE001 - every failure becomes the CLI's one error line
        if _SIGINT[0]:
            raise Interrupted() from None
        if isinstance(exc, addon.pdehead_addon.PDEHeadError):
            raise CLIError(state.user_text(str(exc)), 2) from None
        traceback.print_exc()
        raise CLIError(f"PDE Head internal error: {type(exc).__name__}: {exc}", 1) from None
    finally:
        WARNINGS.from_study()
    return result


def _study_step(coll, step: str, report, **settings):
    """Run one of the study's steps (``Study.segment``, ``boundaries``, ``surface``, ``solid``, ``volume``) with
    ``settings`` stored first, as its operator does, and print the operator's INFO report from the outcome it
    returns (errors and warnings: :func:`_step`). Returns the outcome."""
    addon = sys.modules[_common.DEV_PACKAGE]
    state = addon.operators.state
    study = addon.operators.study.entity.Study.of(coll)

    def work():
        with state.suspended_updates():
            for name, value in settings.items():
                setattr(study.settings, name, value)
        if step in ("surface", "solid", "volume") and study.boundary_set() is None:
            study.boundaries()
        return getattr(study, step)()
    return _step(work, lambda outcome: [report(study, outcome)])


class Warnings:
    """Each warning once, as one line ``pdehead: warning: ...`` on stderr, in the CLI's words (flags):
    the study's warnings after every step, and Python warnings (the engine's, without their source line)."""

    def __init__(self):
        self.printed: list[str] = []

    def say(self, message: str) -> None:
        addon = sys.modules.get(_common.DEV_PACKAGE)
        if addon is not None:
            message = addon.operators.state.user_text(message)
        message = " ".join(str(message).split())
        if message and not any(message in p or p in message for p in self.printed):
            self.printed.append(message)
            print(f"{PROG}: warning: {message}", file=sys.stderr, flush=True)

    def from_study(self) -> None:
        import bpy
        addon = sys.modules[_common.DEV_PACKAGE]
        coll = bpy.context.scene.pdehead.active_study
        if coll is not None:
            for warning in addon.operators.study.entity.Study.of(coll).warnings:
                self.say(warning)

    def showwarning(self, message, category, filename, lineno, file=None, line=None) -> None:
        self.say(str(message))


WARNINGS = Warnings()


def loader_kwargs(args) -> dict:
    kwargs: dict = {}
    if args.input is None:
        return kwargs
    path = Path(args.input).resolve()
    if path.is_dir():
        kwargs["directory"] = str(path)
    elif args.format in ("auto", "dicom") and _dicom_series_file(path):
        # one DICOM file of a series: the series it belongs to, from its folder (the dialog's rule)
        kwargs.update(directory=str(path.parent), filepath=str(path), single_file=False)
    else:
        kwargs["filepath"] = str(path)
        kwargs["single_file"] = True
    kwargs["format"] = args.format.upper()
    if args.format == "raw":
        from pdehead_dev.operators.ui.import_options import parse_dtype_string
        from pdehead_dev.pdehead_addon import PDEHeadError
        try:
            dtype, order = parse_dtype_string(args.dtype)
        except PDEHeadError as exc:
            raise CLIError(str(exc), 2) from None
        kwargs.update(raw_shape=tuple(args.raw_shape), raw_dtype=dtype, byte_order=order)
    if args.spacing:
        kwargs["spacing"] = tuple(args.spacing)
        kwargs["use_spacing"] = True
    if args.first_slice and args.first_slice != "auto":
        kwargs["first_slice"] = args.first_slice.upper()
    if args.orientation:
        kwargs["orientation"] = args.orientation.upper()
    if args.units:
        kwargs["units"] = args.units.upper()
    if args.series_uid:
        kwargs["series_uid"] = args.series_uid
    if args.downsample > 1:
        kwargs["downsample"] = args.downsample
    return kwargs


def _dicom_series_file(path: Path) -> bool:
    from pdehead_dev.pdehead_addon.io.ct_import.discovery import series_of_file
    return series_of_file(path) is not None


def _auto_boundaries(args, addon, coll) -> str:
    """Automatic slice selection through the study's boundaries step (``selection="auto"``, or a tolerance
    that chooses the count); returns the summary line."""
    if args.no_align:
        raise CLIError("--selection auto needs the aligned (angular) curves; drop --no-align", 2)
    if args.tolerance is not None or args.max_tolerance is not None:
        tolerance = dict(use_tolerance=True, tolerance_mm=args.tolerance or 0.0,
                         max_tolerance_mm=args.max_tolerance or 0.0)
    else:
        tolerance = dict(use_tolerance=False)
    _study_step(coll, "boundaries", addon.operators.ui.ops.boundaries_report, patches=args.patches,
                samples=args.samples, selection="auto", align_curves=True, **tolerance)
    s = coll.pdehead
    bset = addon.operators.state.cache_for(s.study_id).bset
    m = bset.meta
    asked = ""
    if m.get("selection_tolerance_mm") is not None or m.get("selection_max_tolerance_mm") is not None:
        def mm(value):  # the tolerances went through float32 properties: 0.3, not 0.30000001192092896
            return "none" if value is None else f"{float(value):.4g}"
        asked = (f"; asked mean <= {mm(m.get('selection_tolerance_mm'))} mm, max <= "
                 f"{mm(m.get('selection_max_tolerance_mm'))} mm: "
                 + ("met" if m.get("selection_tolerance_met") else "NOT met (every usable slice used)"))
    return (f"auto: {m['selection_curves']} curves of {m['selection_candidates']} usable slices; surface from all "
            f"outlines mean {m['selection_mean_mm']:.3f} mm, p95 {m['selection_p95_mm']:.2f} mm, "
            f"max {m['selection_max_mm']:.2f} mm{asked}")


def _check_writable_folder(folder: Path, flag: str) -> None:
    """Exit 2 (before any work) when ``folder`` cannot be created or written."""
    if folder.exists() and not folder.is_dir():
        raise CLIError(f"{flag} {folder}: not a folder", 2)
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir() or not os.access(existing, os.W_OK | os.X_OK):
        raise CLIError(f"{flag} {folder}: cannot write there ({existing} is not a writable folder)", 2)


def _outputs(args) -> list[Path]:
    """The folders the run writes into directly: --export and --render-animation (the .blend, its volume
    and the renders go through :class:`Staging`)."""
    return [Path(p).resolve() for p in (args.export, args.render_animation) if p is not None]


def _snapshot(paths: list[Path]) -> set[Path]:
    """The files and folders that exist now at or under ``paths`` (and their parents)."""
    found: set[Path] = set()
    for p in paths:
        for q in (p, *p.parents):
            if q.exists():
                found.add(q)
        if p.is_dir():
            found.update(p.rglob("*"))
    return found


def _remove_new(paths: list[Path], before: set[Path]) -> None:
    """Delete what the run created at or under ``paths`` (files, then folders it made), nothing else."""
    created = _snapshot(paths) - before
    for q in sorted(created, key=lambda x: len(x.parts), reverse=True):
        try:
            q.rmdir() if q.is_dir() else q.unlink()
        except OSError:
            pass


#: Held while outputs are moved into place or removed: a forced exit (:class:`Watchdog`) waits for it.
_OUTPUTS_LOCK = threading.RLock()
#: What a forced exit must remove (each a callable; :class:`Staging` and the temporary Blender folder).
_CLEANUPS: list = []


class Staging:
    """This run's outputs, written privately and moved into place only at the end.

    The .blend and its volume go into a private folder next to ``--out`` (``.pdehead-run-<stem>-XXXX/``,
    made with :func:`tempfile.mkdtemp`: no two runs share one), the renders into one next to each
    image; :meth:`commit` then links each .vdb into ``pdehead_vdb/`` beside ``--out`` under a name no
    other file has (never overwriting another run's or file's volume), re-pointing the volume if the
    name had to change, and renames the .blend and the images into place (``os.replace``: atomic).
    :meth:`discard` (Ctrl-C, a failure) removes the private folders and whatever this run alone
    placed, nothing else.
    """

    def __init__(self, args):
        self.out = args.out.resolve() if args.out else None
        self.folders: dict[Path, Path] = {}      # destination folder -> private folder
        self.made: list[Path] = []               # folders this run created (removed if left empty)
        self.placed: list[Path] = []             # files moved into place while committing
        self.pending: list[tuple[Path, Path]] = []
        self.committed = False
        self.blend = self.private(self.out) if self.out else None

    def _make_folder(self, folder: Path) -> None:
        missing = [q for q in (folder, *folder.parents) if not q.exists()]
        folder.mkdir(parents=True, exist_ok=True)
        self.made.extend(missing)

    def private(self, dest: Path) -> Path:
        """Where to write ``dest`` for now: the same name in this run's private folder beside it."""
        dest = Path(dest).resolve()
        folder = self.folders.get(dest.parent)
        if folder is None:
            self._make_folder(dest.parent)
            folder = Path(tempfile.mkdtemp(prefix=f".pdehead-run-{dest.stem[:40]}-", dir=dest.parent))
            self.folders[dest.parent] = folder
        return folder / dest.name

    def add(self, tmp: Path, dest: Path) -> None:
        """Move ``tmp`` to ``dest`` at :meth:`commit`."""
        self.pending.append((Path(tmp), Path(dest).resolve()))

    def commit(self, bpy, addon) -> None:
        with _OUTPUTS_LOCK:
            if _SIGINT[0]:
                raise Interrupted()
            if self.blend is not None:
                self._commit_blend(bpy, addon)
            for tmp, dest in self.pending:
                if not tmp.is_file():
                    raise CLIError(f"{dest}: was not written", 1)
                os.replace(tmp, dest)
                self.placed.append(dest)
            self.committed = True
            self._remove_folders()

    def _commit_blend(self, bpy, addon) -> None:
        vdb_files = addon.operators.volume.vdb_files
        src_folder = (self.blend.parent / vdb_files.VDB_FOLDER_NAME).resolve()
        dst_folder = self.out.parent / vdb_files.VDB_FOLDER_NAME
        renamed = False
        for obj in bpy.data.objects:
            if obj.type != "VOLUME" or obj.get("pdehead_kind") != "volume" or not obj.data.filepath:
                continue
            src = Path(bpy.path.abspath(obj.data.filepath)).resolve()
            if src.parent != src_folder or not src.is_file():
                continue
            if not dst_folder.exists():
                self._make_folder(dst_folder)
            while True:  # a free name, taken atomically (a link fails on an existing name)
                dst = vdb_files.fresh_vdb_path(dst_folder / src.name)
                try:
                    vdb_files.link_or_copy(src, dst)
                    break
                except FileExistsError:
                    continue
            self.placed.append(dst)
            if dst.name != src.name:
                obj.data.filepath = f"//{vdb_files.VDB_FOLDER_NAME}/{dst.name}"
                renamed = True
        if renamed:
            _save(bpy, self.blend, "--out")
        os.replace(self.blend, self.out)

    def _remove_folders(self) -> None:
        for folder in self.folders.values():
            shutil.rmtree(folder, ignore_errors=True)
        for folder in sorted(self.made, key=lambda q: len(q.parts), reverse=True):
            with contextlib.suppress(OSError):
                folder.rmdir()  # only if empty: another run may have put its files there meanwhile

    def user_text(self, text: str) -> str:
        """`text` with this run's private folders named as the destinations the user gave."""
        for dest, folder in self.folders.items():
            text = text.replace(str(folder), str(dest))
        return text

    def discard(self) -> None:
        """Remove this run's private folders and what it placed (not yet committed), nothing else."""
        with _OUTPUTS_LOCK:
            if not self.committed:
                for path in self.placed:
                    with contextlib.suppress(OSError):
                        path.unlink()
            self._remove_folders()


def run(args) -> dict:
    import warnings

    import bpy
    addon = register_addon()
    state = addon.operators.state
    state.REGISTRY.audience = "cli"              # the add-on's messages name this command's flags
    warnings.showwarning = WARNINGS.showwarning  # one line each, no source line
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backups (temporary user folder)
    progress = Progress()
    addon.operators.study.progress.set_hook(progress)
    outputs = _outputs(args)
    before = _snapshot(outputs)
    staging = Staging(args)
    _CLEANUPS.append(staging.discard)
    try:
        return _run(args, bpy, addon, state, staging)
    except (Interrupted, KeyboardInterrupt):
        staging.discard()
        _remove_new(outputs, before)
        raise Interrupted() from None
    except CLIError as exc:
        staging.discard()
        raise CLIError(staging.user_text(str(exc)), exc.code) from None
    except BaseException:
        staging.discard()
        raise
    finally:
        progress.end()
        addon.operators.study.progress.set_hook(None)
        with contextlib.suppress(ValueError):
            _CLEANUPS.remove(staging.discard)


def _run(args, bpy, addon, state, staging) -> dict:
    if staging.blend is not None:
        # The .blend is saved first into the run's private folder (the volume's .vdb goes beside it);
        # it and the .vdb reach --out only when every step worked, so a failed run leaves an existing
        # --out as it was, and another run's files are never touched.
        _save(bpy, staging.blend, "--out")
        _record_sources_for(bpy, addon, staging.out)
    return _steps(args, bpy, addon, state, staging)


def _record_sources_for(bpy, addon, final) -> None:
    """Each save in the private folder records the CT source relative to the final --out (one folder up)."""
    persistence = addon.operators.study.persistence

    @bpy.app.handlers.persistent
    def pdehead_cli_sources(*_args):
        persistence.record_sources(str(final))
    bpy.app.handlers.save_pre.append(pdehead_cli_sources)


def _steps(args, bpy, addon, state, staging) -> dict:
    t0 = time.perf_counter()
    coll, selection_info, skin = _build(args, bpy, addon)
    total = time.perf_counter() - t0

    timings = addon.operators.study.entity.Study.of(coll).timings
    s = coll.pdehead
    _print_study(args, bpy, state, coll, selection_info)
    if args.skull:
        _print_skull(args, addon, coll, skin)
    study = addon.operators.study.entity.Study.of(coll)
    info_lines = [state.user_text(n) for n in study.notes]       # automatic choices: information
    for note in info_lines:
        print(f"  info      {note}")
    warning_lines = [state.user_text(w) for w in study.warnings]
    for warning in warning_lines:
        print(f"  warning   {warning}")
    print("timings (s):")
    for step, seconds in timings.items():
        print(f"  {step:<11}{seconds:8.3f}")
    print(f"  {'total':<11}{total:8.3f}")

    summary = _summary(args, addon, coll, timings, total, selection_info, warning_lines)
    summary["info"] = info_lines
    if args.out:
        _save(bpy, staging.blend, "--out")
    _render(args, addon, s, summary, staging)
    if args.turntable:
        _turntable(args, bpy, addon, coll, summary, staging)
    staging.commit(bpy, addon)
    if args.out:
        print(f"wrote {args.out}")
        summary["outputs"]["blend"] = str(args.out)
        if s.volume_object is not None:
            summary["volume"]["vdb"] = s.volume_object.data.filepath
    else:
        print("not saved: no --out given (pass --out FILE.blend to keep the result)")
    for flag in ("render", "render_volume"):
        if flag in summary["outputs"]:
            print(f"wrote {summary['outputs'][flag]}")
    return summary


def _build(args, bpy, addon):
    """Every step of the study, as the add-on's operators make them (the study's methods): (the study's
    collection, the automatic selection's report or None, whether the scan has skin)."""
    table = _face_table(args, addon)          # a table or sex that cannot be used: exit 2 before the work
    reports = addon.operators.ui.ops
    Study = addon.operators.study.entity.Study
    if args.phantom:
        study = _step(lambda: Study.phantom(bpy.context), lambda made: [reports.phantom_report(made)])
    else:
        def import_ct():
            path, options = addon.operators.ui.import_options.import_request(**loader_kwargs(args))
            made = Study.import_ct(bpy.context, path, options)
            made.settings.use_bone_level = addon.pdehead_addon.defaults.USE_BONE_LEVEL.default   # the dialog's
            return made
        study = _step(import_ct, lambda made: [reports.import_report(made)])
    coll = study.collection
    if table is not None:                     # the study's table: the face's pegs and landmarks.csv use it
        props = _forensic(addon, coll).props
        props.depth_table, props.depth_table_name = table.to_json(), table.label
    s = coll.pdehead
    if args.bone_level is not None:          # the import dialog's / forensic panel's Bone Level field
        s.use_bone_level, s.bone_level = True, args.bone_level
    _study_step(coll, "segment", reports.segment_report)
    if args.selection == "auto":
        selection_info = _auto_boundaries(args, addon, coll)
    else:
        selection_info = None
        _study_step(coll, "boundaries", reports.boundaries_report, patches=args.patches, samples=args.samples,
                    selection=args.selection, align_curves=not args.no_align)
    _study_step(coll, "surface", reports.surface_report, nu=args.nu, nv=args.nv)
    if args.detail is not None:              # the Surface panel's CT Detail toggle, strength and Build CT Detail
        s.use_detail_map, s.detail_strength = True, args.detail
        _step(study.detail_map, lambda outcome: [reports.detail_report(study, outcome)])
    _study_step(coll, "solid", reports.solid_report, nu=args.nu, nv=args.nv, nw=args.nw)
    if not args.no_volume:
        # no size given: the add-on's automatic size (Auto Voxel Size)
        _study_step(coll, "volume", reports.volume_report,
                    **({} if args.voxel_size is None else dict(voxel_auto=False, voxel_size=args.voxel_size)))
    skin = True
    if args.skull:
        fs, forensic_reports = _forensic(addon, coll), addon.operators.ui.forensic_ops
        _step(fs.skull.step_skull, lambda outcome: [forensic_reports.skull_report(fs, outcome)])
        skin = fs.skull.skull_info().get("has_skin", True)
        if skin:
            _step(fs.skull.step_depth, lambda outcome: [forensic_reports.depth_report(outcome)])
        # no landmarks given: the automatic ones, each with its flag (a WARNING report goes to stderr as the
        # study's warnings do, not to stdout)
        if not fs.landmarks():
            _step(fs.find_landmarks, lambda outcome: [text for level, text in [forensic_reports.landmarks_report(
                outcome)] if level == 'INFO'])
        face = _face_from_skull(addon, coll) if args.face_from_skull else None
        if args.export:
            _export_with_face(args, addon, coll, face)
    return coll, selection_info, skin


def _print_study(args, bpy, state, coll, selection_info) -> None:
    """The summary's lines for the CT, the segmentation, the curves, the surface, the solid and the volume."""
    s = coll.pdehead
    print(f"{PROG}: study '{coll.name}'")
    nx, ny, nz = s.dimensions
    dz, dy, dx = s.spacing
    # one order everywhere: x, y, z (columns, rows, slices)
    print(f"  CT        {nx} x {ny} x {nz} voxels (x, y, z), spacing {dx:g} x {dy:g} x {dz:g} mm (x, y, z), "
          f"range {s.value_range[0]:.0f}..{s.value_range[1]:.0f}")
    print(f"  segment   head {100 * s.seg_fraction:.1f} % of voxels, {s.seg_iterations} iterations")
    kb = len(coll[state.BOUNDARY_KEY]) * 3 / 4 / 1024
    curves = s.curve_count or 3 * s.patches + 1
    count = ("counted for the tolerance" if s.use_tolerance else f"t = {s.patches}") + f", {args.selection} selection"
    print(f"  curves    {curves} x {s.samples} points ({count}), {kb:.0f} kB in the .blend")
    if selection_info:
        print(f"  selection {selection_info}")
    print(f"  surface   {len(s.surface_object.data.vertices)} vertices, {len(s.surface_object.data.polygons)} faces")
    print(f"  solid     {len(s.solid_object.data.vertices)} vertices")
    if s.volume_object is not None:
        size = "CT grid" if s.use_ct_grid else f"{s.voxel_size:g} mm voxels" + (" (automatic)" if s.voxel_auto else "")
        vdb = s.volume_object.data.filepath
        where = args.out.resolve().parent / vdb[2:] if args.out and vdb.startswith("//") else bpy.path.abspath(vdb)
        print(f"  volume    {where}, {size}")


def _print_skull(args, addon, coll, skin) -> None:
    """The summary's lines for the skull, the skin, the depth map, the landmarks, the face and the export."""
    fs = _forensic(addon, coll)
    info, depth = fs.skull.skull_info(), fs.skull.depth_stats()
    if info.get("skull_mesh_file"):
        level = f"none (the skull is the mesh {info['skull_mesh_file']})"
    else:
        level = f"{info.get('bone_level_stored', info.get('bone_level', 0)):g} {info.get('units', 'HU')}"
    print(f"  skull     bone level {level}, {info.get('patches')} patches, "
          f"{info.get('bone_triangles', 0)} bone-skull triangles")
    if not skin:
        soft = info.get("soft_tissue") or {}
        ratio, limit = soft.get("layer_ratio"), soft.get("layer_ratio_limit")
        share, share_limit = soft.get("soft_tissue_share"), soft.get("soft_tissue_share_limit")
        why = "" if ratio is None or limit is None else (
            f": the layer under its surfaces lies {ratio:.2f} of the way from air to dense bone, soft tissue below "
            f"{limit:g}")
        if share is not None and share_limit is not None and share < share_limit:
            lo, hi = soft.get("soft_tissue_hu", (float("nan"), float("nan")))
            why += (f"{'; ' if why else ': '}{100 * share:.1f} % of its non-air voxels lie at soft tissue's values "
                    f"({lo:g} to {hi:g} HU), a head has at least {100 * share_limit:.0f} %")
        print(f"  skin      none: the scan has no soft tissue (a skull alone{why}): no skin.stl, no tissue_depth.csv, "
              "no landmark depths")
    if "median" in depth:
        print(f"  depth     {depth['measured']} of {depth['vertices']} skin vertices, median {depth['median']:.1f} "
              f"mm, p95 {depth['p95']:.1f} mm (no bone {depth['no_bone']}, envelope {depth['envelope']})")
    flags = list(_output_flags(fs).values())
    if flags:
        print(f"  landmarks {len(flags) - flags.count('not_found')} of {len(flags)} found automatically "
              f"({flags.count('ok')} ok, {flags.count('uncertain')} uncertain, {flags.count('not_found')} not found)")
    if getattr(args, "face", None) is not None:
        res, model = args.face
        prov = res.provenance
        print(f"  face      {model.label}: {len(model.peg_names)} pegs, table {prov.get('table', 'imported table')}, "
              f"{len(res.mesh.vertices)} vertices, closed")
    if args.export:
        written = sorted(p.name for p in args.export.iterdir() if not p.name.startswith("."))
        print(f"  export    {args.export}: {', '.join(written)}")


def _output_flags(fs) -> dict:
    """The landmarks' flags as the outputs carry them: those the export wrote (landmarks.csv and the face's
    provenance), else Find Landmarks' own."""
    return fs.cache.get("export_flags") or {name: flag for name, (flag, _) in fs.landmark_flags().items()}


def _render(args, addon, s, summary, staging) -> None:
    """--render and --render-volume (into the run's private folder; moved into place by the commit)."""
    render = addon.operators.scene.render
    size = (args.resolution, args.resolution)
    for flag, obj in (("render", s.surface_object), ("render_volume", s.volume_object)):
        path = getattr(args, flag)
        if path is None:
            continue
        t = time.perf_counter()
        written = render.render_objects_png([obj], staging.private(path), view=args.view, resolution=size,
                                            samples=args.render_samples)
        if _SIGINT[0]:
            raise Interrupted()
        if not Path(written).is_file() or Path(written).stat().st_size == 0:
            raise CLIError(f"--{flag.replace('_', '-')} {path}: the render was not written", 1)
        staging.add(written, path)
        print(f"  rendered  {path.name} ({time.perf_counter() - t:.1f} s)")
        summary["outputs"][flag] = str(path)


def _turntable(args, bpy, addon, coll, summary, staging) -> None:
    """--turntable (saved into --out again) and --render-animation."""
    size = (args.resolution, args.resolution)
    study = addon.operators.study.entity.Study.of(coll)
    scene = bpy.context.scene
    _step(lambda: addon.operators.study.animation.turntable(bpy.context, coll, args.turntable,
                                                            start=scene.frame_start),
          lambda pivot: [addon.operators.ui.ops.turntable_report(study, pivot, args.turntable)])
    print(f"  turntable {args.turntable} frames (1..{args.turntable}) around '{coll.name}'")
    if args.out:
        _save(bpy, staging.blend, "--out")
    if args.render_animation:
        t = time.perf_counter()
        with _blender_stdout(drop=("Fra:", "Time:", "Saved:", "Info:")):
            paths = addon.operators.study.animation.render_animation(bpy.context.scene, args.render_animation.resolve(),
                                                               size, args.render_samples)
        print(f"wrote {len(paths)} frames {paths[0]} .. {paths[-1].name} ({time.perf_counter() - t:.1f} s)")
        summary["outputs"]["render_animation"] = [str(x) for x in paths]


def _forensic(addon, coll):
    """The study's forensic side (operators/forensic/study.py's ForensicStudy)."""
    study = addon.operators.study.entity.Study.of(coll)
    return addon.operators.forensic.study.ForensicStudy.of(study)


def _face_table(args, addon):
    """The depth table of --depth-table FILE (default: the shipped T-Table 2023) with the rows of --sex, or None
    when neither is given (the study's table). A file that is no depth table, or a sex the table has no values
    for, is exit 2."""
    if args.depth_table is None and args.sex is None:
        return None
    engine = addon.pdehead_addon
    try:
        table = engine.read_depth_table(args.depth_table) if args.depth_table else engine.default_table()
    except engine.PDEHeadError as exc:
        raise CLIError(f"--depth-table {exc}", 2) from None
    try:
        return table.for_sex(args.sex)
    except engine.PDEHeadError as exc:
        flag = f"--sex {args.sex}" if args.sex else "--depth-table"
        raise CLIError(f"{flag}: {exc}" + (" (drop --sex)" if args.sex and not table.sexes else ""), 2) from None


def _face_from_skull(addon, coll):
    """The face approximated from the study's bone skull, landmarks and depth table: (result, model).
    A skull the engine refuses (too few landmarks with a depth, not a skull in mm) is exit 2."""
    from importlib import import_module
    ff = import_module(addon.__name__ + ".pdehead_addon.forensic.face_from_skull")
    fs = _forensic(addon, coll)
    try:
        table = fs.outputs.depth_table()
        model = ff.FaceModel.prepare(fs.skull.skull_engine_mesh("BONE"), fs.landmarks(), table, sex=table.sex or None,
                                     flags=fs.flag_names())
        res = model.solve()
    except addon.pdehead_addon.PDEHeadError as exc:
        raise CLIError(f"--face-from-skull: {exc}", 2) from None
    if not res.mesh.is_watertight():
        raise CLIError("--face-from-skull: the face mesh is not closed; nothing was written", 1)
    model.label = ff.APPROXIMATION_LABEL
    fs.study.record_timing("face_prep", model.prepare_seconds)      # steps of the run, in the order they ran
    fs.study.record_timing("face_solve", res.timings["total"])
    off = res.pegs.summary() if res.pegs is not None else None
    if off:                                 # the face passes near, not through, these tips (damped, shaped)
        WARNINGS.say(f"--face-from-skull: {off} (reasons in the face's provenance, pegs_off_face)")
    prov = dict(fs.outputs.provenance(fs.outputs.depth_table()), **res.provenance)
    res.provenance = prov
    return res, model


def _export_with_face(args, addon, coll, face) -> None:
    """Export for printing, plus face.<fmt> when the face was made: the study's export writes the face with the
    rest (built and checked first, then moved into place: nothing half-written), its provenance's landmark
    flags the same as landmarks.csv's. The written files are kept in ``args.written`` (name -> path)."""
    out = args.export.resolve()
    args.face = face
    fs = _forensic(addon, coll)
    if face is None:
        outcome = _step(lambda: fs.outputs.export(str(out), args.export_format),
                        addon.operators.ui.forensic_ops.export_report)
        files = [Path(f) for f in outcome.values["files"]]
    else:
        res, _model = face
        try:
            outcome = fs.outputs.export(str(out), args.export_format, face=(res.head, res.provenance))
            files = [Path(f) for f in outcome.values["files"]]
        except addon.pdehead_addon.Cancelled:
            raise Interrupted() from None
        except addon.pdehead_addon.PDEHeadError as exc:
            raise CLIError(f"--export {args.export}: {exc}", 2) from None
        finally:
            WARNINGS.from_study()
    # "skull", "face", ... for the meshes (their format is --export-format), the file name for the others
    mesh_suffix = "." + args.export_format
    args.written = {(f.stem if f.suffix == mesh_suffix else f.name): str(f) for f in files}


def _save(bpy, path: Path, flag: str) -> None:
    """Save the .blend at ``path``; a file that cannot be written is a one-line error (exit 2)."""
    try:
        with _blender_stdout(drop=("Info: Saved", "Error:", "Warning:")):
            bpy.ops.wm.save_as_mainfile(filepath=str(path))
    except RuntimeError as exc:
        reason = " ".join(str(exc).split()).removeprefix("Error: ")
        raise CLIError(f"{flag} {path}: cannot be written ({reason})", 2) from None
    if not path.is_file() or path.stat().st_size == 0:
        raise CLIError(f"{flag} {path}: cannot be written (no file after the save; disk full?)", 2)


def _r(value, digits: int = 3):
    """A number rounded for people (and for --summary-json)."""
    return float(f"{float(value):.{digits}g}") if digits else round(float(value))


def _summary(args, addon, coll, timings, total, selection_info, warning_lines) -> dict:
    """What the summary printed, as data (``--summary-json``)."""
    s = coll.pdehead
    ct = addon.operators.state.cache_for(s.study_id).ct
    meta = getattr(ct, "meta", None) or {}
    nx, ny, nz = s.dimensions
    dz, dy, dx = s.spacing
    out = {
        "status": "ok", "exit_code": 0,
        "input": "phantom" if args.phantom else str(args.input),
        "study": coll.name,
        "ct": {"voxels_xyz": [nx, ny, nz], "spacing_mm_xyz": [_r(dx, 4), _r(dy, 4), _r(dz, 4)],
               "value_range": [_r(s.value_range[0], 0), _r(s.value_range[1], 0)],
               "orientation": meta.get("orientation", ""), "first_slice": meta.get("first_slice", "")},
        "segment": {"head_percent": round(100 * s.seg_fraction, 1), "iterations": int(s.seg_iterations)},
        "curves": {"count": int(s.curve_count or 3 * s.patches + 1), "samples": int(s.samples),
                   "patches": None if s.use_tolerance else int(s.patches), "selection": args.selection},
        "surface": {"vertices": len(s.surface_object.data.vertices), "faces": len(s.surface_object.data.polygons)},
        "solid": {"vertices": len(s.solid_object.data.vertices)},
        "timings_s": {step: round(float(sec), 3) for step, sec in timings.items()},
        "total_s": round(total, 3),
        "warnings": list(warning_lines),
        "outputs": {},
    }
    if selection_info:
        out["selection"] = selection_info
    out["outputs"].update(getattr(args, "written", {}))
    if args.skull:
        fs = _forensic(addon, coll)
        flags = list(_output_flags(fs).values())
        out["landmarks"] = {flag: flags.count(flag) for flag in ("ok", "uncertain", "not_found")}
    if getattr(args, "face", None) is not None:
        res, model = args.face
        out["face"] = {"label": model.label, "table": res.provenance.get("table", "imported table"),
                       "pegs": len(model.peg_names), "vertices": len(res.mesh.vertices),
                       "landmarks": out["landmarks"]}
    if s.volume_object is not None:
        out["volume"] = {"vdb": s.volume_object.data.filepath,
                         "voxel_size_mm": None if s.use_ct_grid else _r(s.voxel_size, 4)}
    return out


def write_summary_json(path: Path, summary: dict) -> None:
    """Write atomically (a temporary file beside it, then renamed): never a half-written file."""
    path = Path(path)
    data = (json.dumps(summary, indent=1) + "\n").encode("utf-8")
    tmp = None
    try:  # a temporary name of this run's own (two runs never share one), its size checked, then renamed
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
        tmp = Path(name)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if tmp.stat().st_size != len(data):
            raise OSError(f"{tmp.stat().st_size} of {len(data)} bytes written")
        os.replace(tmp, path)
    except OSError as exc:
        raise CLIError(f"--summary-json {path}: cannot be written ({exc.strerror or exc})", 2) from None
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)


def main(argv=None, watchdog: bool = False) -> int:
    """The CLI; ``watchdog``: also end the process within about a second of Ctrl-C when a step does not stop
    by itself (:class:`Watchdog`; only for the script itself: it may end the process)."""
    args = None
    user_folder = private_tmp = saved_tempdir = None
    guard = None
    try:
        args = parse_args(argv)
        # Keep Blender away from the real user folder (must precede `import bpy`); ours is removed at the end.
        if "BLENDER_USER_RESOURCES" not in os.environ:
            user_folder = tempfile.mkdtemp(prefix="pdehead-cli-")
            os.environ["BLENDER_USER_RESOURCES"] = user_folder
            _CLEANUPS.append(lambda: shutil.rmtree(user_folder, ignore_errors=True))
        # The run's temporary files (the .vdb of a run without --out, captured output) go into a private
        # folder removed at exit, not into the shared system temp folder (Blender's own stays as it is).
        private_tmp, saved_tempdir = tempfile.mkdtemp(prefix="pdehead-cli-tmp-"), tempfile.tempdir
        tempfile.tempdir = private_tmp
        previous = signal.signal(signal.SIGINT, _on_sigint)
        if watchdog:
            guard = Watchdog()
        try:
            summary = run(args)
        finally:
            signal.signal(signal.SIGINT, previous)
        if args.summary_json:
            write_summary_json(args.summary_json, summary)
            print(f"wrote {args.summary_json}")
    except (Interrupted, KeyboardInterrupt):
        print(f"{PROG}: cancelled (Ctrl-C); no output was written", file=sys.stderr)
        return 130
    except CLIError as exc:
        if _SIGINT[0]:
            print(f"{PROG}: cancelled (Ctrl-C); no output was written", file=sys.stderr)
            return 130
        message = " ".join(str(exc).split())
        print(f"{PROG}: error: {message}", file=sys.stderr)
        if args is not None and args.summary_json and "--summary-json" not in message:
            with contextlib.suppress(CLIError):  # scripts read the failure from the file too
                write_summary_json(args.summary_json, {"status": "error", "exit_code": exc.code, "error": message,
                                                       "warnings": list(WARNINGS.printed)})
        return exc.code
    finally:
        if guard is not None:
            guard.close()
        if private_tmp is not None:        # every exit, as the user folder below
            tempfile.tempdir = saved_tempdir
            shutil.rmtree(private_tmp, ignore_errors=True)
        if user_folder is not None:        # every exit: 0, 1 (an uncaught error), 2 and 130
            shutil.rmtree(user_folder, ignore_errors=True)
            if os.environ.get("BLENDER_USER_RESOURCES") == user_folder:
                del os.environ["BLENDER_USER_RESOURCES"]
    return 0


if __name__ == "__main__":
    sys.exit(main(watchdog=True))
