"""The CT loader options of the File > Import dialog and of the one-click pipeline (an operator mixin).

:class:`LoaderOptions` holds the operator properties (format, raw shape and type, spacing,
orientation, downsampling, series) and turns them into the engine's ``load_ct`` keyword
arguments (:meth:`LoaderOptions.loader_options`).
"""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import bpy
import numpy as np
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatVectorProperty,
    IntProperty,
    IntVectorProperty,
    StringProperty,
)
from bpy.types import OperatorFileListElement

from ...pdehead_addon import CTImportError, defaults as D, series_of_file
from ..study import props

FORMAT_ITEMS = [
    ("AUTO", "Auto", "Detect DICOM series or numbered 2-D images (TIFF, PNG)"),
    ("DICOM", "DICOM", "A DICOM series (folder or one of its files)"),
    ("IMAGES", "Image Stack", "Numbered 2-D images, one slice per file"),
    ("RAW", "Raw", "Headerless raw slices (give shape, type, byte order, spacing)"),
]
DTYPE_ITEMS = [
    ("i2", "int16", "Signed 16-bit"),
    ("u2", "uint16", "Unsigned 16-bit"),
    ("u1", "uint8", "Unsigned 8-bit"),
    ("i4", "int32", "Signed 32-bit"),
    ("f4", "float32", "32-bit float"),
]
BYTE_ORDER_ITEMS = [("BIG", "Big Endian", "Most significant byte first ('>')"),
                    ("LITTLE", "Little Endian", "Least significant byte first ('<')")]
FIRST_SLICE_ITEMS = [("AUTO", "Auto", "DICOM: from the file headers. Raw and image stacks: the first file is "
                                     "inferior, unless the head's crown (where it closes) is at the first file: "
                                     "then superior (said as information in the Study panel)"),
                     ("SUPERIOR", "Superior", "The first file is the top of the head"),
                     ("INFERIOR", "Inferior", "The first file is the bottom (neck)")]


def dtype_string(dtype: str, byte_order: str) -> str:
    """numpy dtype string of the raw options, e.g. ('i2', 'BIG') -> '>i2'."""
    if dtype == "u1":
        return "u1"
    return (">" if byte_order == "BIG" else "<") + dtype


def parse_dtype_string(text: str) -> tuple[str, str]:
    """Inverse of :func:`dtype_string`: '>i2' -> ('i2', 'BIG'); '|u1' / 'uint8' -> ('u1', ...)."""
    try:
        dt = np.dtype(text)
    except TypeError:
        raise CTImportError(f"unknown data type '{text}' (use e.g. '>i2', '<u2', 'u1', '<f4')") from None
    code = f"{dt.kind}{dt.itemsize}"
    if code not in {item[0] for item in DTYPE_ITEMS}:
        raise CTImportError(f"unsupported raw data type '{text}'")
    order = "BIG" if dt.byteorder == ">" else "LITTLE"
    return code, order


def _orientation_units_downsample(loader, options: dict) -> None:
    """Add the slice order (an explicit orientation, else a first slice other than Auto: the engine's rule,
    defaults.FIRST_SLICE), the units and the downsampling of ``loader`` (the loader settings) to ``options``."""
    if loader.orientation.strip():
        options["orientation"] = loader.orientation.strip().upper()
    elif loader.first_slice != "AUTO":
        options["first_slice"] = loader.first_slice.lower()
    if loader.units != "AUTO":
        options["units"] = "HU" if loader.units == "HU" else "stored"
    if loader.downsample > 1:
        options["downsample"] = int(loader.downsample)


@props.settings_options("use_bone_level", "bone_level", mirrored=False)
class LoaderOptions:
    """Operator properties of the CT loaders (mixed into import_ct and run_pipeline); the forensic bone level is
    the study's setting (:mod:`operators.study.props`)."""

    directory: StringProperty(name="Folder", subtype="DIR_PATH", options={'HIDDEN', 'SKIP_SAVE'})
    filepath: StringProperty(name="File Path", subtype="FILE_PATH", options={'HIDDEN', 'SKIP_SAVE'})
    files: CollectionProperty(type=OperatorFileListElement, options={'HIDDEN', 'SKIP_SAVE'})
    filter_glob: StringProperty(default="*", options={'HIDDEN'})
    single_file: BoolProperty(name="Only the Selected File", default=False,
                              description="Read only the selected file (a single-file volume), "
                                          "not the whole folder")
    format: EnumProperty(name="Format", items=FORMAT_ITEMS, default="AUTO")
    raw_shape: IntVectorProperty(name=D.RAW_SHAPE.label, size=2, **D.RAW_SHAPE.limits(),
                                 description=D.RAW_SHAPE.description)
    raw_dtype: EnumProperty(name=D.RAW_DTYPE.label, items=DTYPE_ITEMS, default=D.RAW_DTYPE.default,
                            description=D.RAW_DTYPE.description)
    byte_order: EnumProperty(name=D.BYTE_ORDER.label, items=BYTE_ORDER_ITEMS, default=D.BYTE_ORDER.default,
                             description=D.BYTE_ORDER.description)
    use_spacing: BoolProperty(name=D.USE_SPACING.label, **D.USE_SPACING.limits(),
                              description=D.USE_SPACING.description)
    spacing: FloatVectorProperty(name=D.IMPORT_SPACING.label, size=3, **D.IMPORT_SPACING.limits(),
                                 description=D.IMPORT_SPACING.description)
    first_slice: EnumProperty(name="First Slice", items=FIRST_SLICE_ITEMS, default=D.FIRST_SLICE.upper())
    orientation: StringProperty(name="Orientation", default="",
                                description="Raw and image stacks: 3 letters for the patient directions in "
                                            "which the column, row and file index increase, e.g. LPS (the "
                                            "default), LAS (row 0 = back of the head), RAS, PIL (sagittal). "
                                            "Empty: First Slice decides (Auto: LPS, or LPI when the crown is "
                                            "at the first file)")
    units: EnumProperty(name="Units", default="AUTO",
                        items=[("AUTO", "Auto", "DICOM says its units; raw and images are stored values"),
                               ("HU", "HU", "The raw or image samples are Hounsfield units (air -1000)"),
                               ("STORED", "Stored", "The raw, image or NIfTI samples are stored values, not HU "
                                                    "(what Auto assumes for them; DICOM says its own units)")])
    downsample: IntProperty(name=D.DOWNSAMPLE.label, **D.DOWNSAMPLE.limits(), description=D.DOWNSAMPLE.description)
    series_uid: StringProperty(name="Series UID", default="",
                               description="DICOM: the SeriesInstanceUID to load when the folder "
                                           "holds several series (empty: the only/largest one)")

    def apply_study_options(self, coll) -> None:
        """Options of the dialog that belong to the study, not the loader (the forensic bone level)."""
        s = coll.pdehead
        s.use_bone_level = bool(self.use_bone_level)
        if self.use_bone_level:
            s.bone_level = float(self.bone_level)

    def input_path(self) -> Path:
        if self.directory and not self.single_file:
            path = bpy.path.abspath(self.directory)
        elif self.filepath:
            path = bpy.path.abspath(self.filepath)
        elif self.directory:
            path = bpy.path.abspath(self.directory)
        else:
            raise CTImportError("no file or folder given")
        path = Path(path)
        if not path.exists():
            raise CTImportError("no such file or folder", path)
        return path

    def loader_options(self) -> dict:
        options: dict = {}
        if self.format == "RAW":
            options.update(format="raw", shape=tuple(int(n) for n in self.raw_shape),
                           dtype=dtype_string(self.raw_dtype, self.byte_order),
                           spacing=tuple(float(s) for s in self.spacing))
            _orientation_units_downsample(self, options)
            return options
        if self.format == "DICOM":
            options["format"] = "dicom"
        elif self.format == "IMAGES":
            options["format"] = "images"
        if self.use_spacing:
            options["spacing"] = tuple(float(s) for s in self.spacing)
        _orientation_units_downsample(self, options)
        if self.series_uid.strip():
            options["series_uid"] = self.series_uid.strip()
        elif self.format in {"AUTO", "DICOM"} and self.filepath and not self.single_file:
            # one DICOM file chosen: the series it belongs to, from its folder (not the folder's largest)
            uid = series_of_file(bpy.path.abspath(self.filepath))
            if uid:
                options["series_uid"] = uid
        return options

    def draw_loader_options(self, layout) -> None:
        layout.prop(self, "format")
        if self.format == "RAW":
            layout.prop(self, "raw_shape")
            layout.prop(self, "raw_dtype")
            if self.raw_dtype != "u1":
                layout.prop(self, "byte_order")
            layout.prop(self, "spacing")
        else:
            layout.prop(self, "use_spacing")
            if self.use_spacing:
                layout.prop(self, "spacing")
        layout.prop(self, "first_slice")
        if self.format in {"AUTO", "IMAGES", "RAW"}:
            layout.prop(self, "orientation")
            layout.prop(self, "units")
        if self.format in {"AUTO", "DICOM"}:
            layout.prop(self, "series_uid")
        layout.prop(self, "downsample")
        layout.prop(self, "single_file")
        row = layout.row(heading="Forensic")
        row.prop(self, "use_bone_level")
        sub = row.row()
        sub.active = self.use_bone_level
        sub.prop(self, "bone_level", text="")




def import_request(directory: str = "", filepath: str = "", single_file: bool = False, format: str = "AUTO",
                   raw_shape=D.RAW_SHAPE.default, raw_dtype: str = D.RAW_DTYPE.default,
                   byte_order: str = D.BYTE_ORDER.default, use_spacing: bool = D.USE_SPACING.default,
                   spacing=D.IMPORT_SPACING.default, first_slice: str = D.FIRST_SLICE.upper(), orientation: str = "",
                   units: str = "AUTO", downsample: int = D.DOWNSAMPLE.default,
                   series_uid: str = "") -> tuple[Path, dict]:
    """The CT and the engine's loader options (``Study.import_ct``'s arguments) of the import dialog's values
    (the keywords of ``bpy.ops.pdehead.import_ct``, the dialog's defaults for those not given): how a script or
    the CLI imports without the operator."""
    values = SimpleNamespace(**locals())
    return LoaderOptions.input_path(values), LoaderOptions.loader_options(values)


#: What a drag and drop onto the 3D View opens with the import dialog (:class:`PDEHEAD_FH_import_ct`):
#: file name ending -> the dialog's format and whether the file alone is read (a NIfTI volume) or its
#: folder (a DICOM series, an image or raw stack). DICOM files without an extension: drop one of
#: them on the File > Import dialog (a FileHandler matches by extension).
DROP_FORMATS = {".dcm": ("DICOM", False), ".ima": ("DICOM", False), ".nii": ("AUTO", True),
                ".nii.gz": ("AUTO", True), ".tif": ("IMAGES", False), ".tiff": ("IMAGES", False),
                ".raw": ("RAW", False)}


def dropped_file_options(directory: str, names) -> dict:
    """The import dialog's properties for files dropped from ``directory`` (their ``names``):
    ``directory`` / ``filepath``, ``single_file`` and ``format`` of the first recognised file."""
    for name in names:
        lower = name.lower()
        for ending, (fmt, single) in sorted(DROP_FORMATS.items(), key=lambda kv: -len(kv[0])):
            if lower.endswith(ending):
                path = str(Path(directory) / name)
                return dict(directory=str(directory), filepath=path, single_file=single, format=fmt)
    return {}


class PDEHEAD_FH_import_ct(bpy.types.FileHandler):
    """Drag and drop of a DICOM file (its series), a .nii / .nii.gz volume or a raw / TIFF slice (its
    stack) onto the 3D View: the CT import dialog opens with it (Blender 4.1+)."""

    bl_idname = "PDEHEAD_FH_import_ct"
    bl_label = "PDE Head CT"
    bl_import_operator = "pdehead.import_ct"
    bl_file_extensions = ";".join(DROP_FORMATS)

    @classmethod
    def poll_drop(cls, context):
        area = getattr(context, "area", None)
        return area is not None and area.type == "VIEW_3D"
