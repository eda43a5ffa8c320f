"""Soft-tissue depth tables: the shipped default (T-Table 2023), CSV reading, and ``landmarks.csv``.

A depth table gives, per craniometric landmark, the mean facial soft-tissue thickness (FSTT) in mm,
its standard deviation and the sample size. The default table shipped with PDE Head
(``data/t_table_2023.csv``) is the 2023 T-Table's pooled grand means and SDs:

    Hona TWPT, Stephan CN. Global facial soft tissue thicknesses for craniofacial identification
    (2023): a review of 140 years of data since Welcker's first study. Int J Legal Med
    138(2):519-535 (2024), doi:10.1007/s00414-023-03087-x

values as printed in the public repository esomjai/Forensic-Craniofacial-Approximation-Validation-Tool
(FSTT/Generating FSTT cylinders in Slicer.md), which attributes them to this paper; check them
against the paper before casework.

**Convention.** The depth is measured from the bone landmark to the skin along the bone's surface
normal at the landmark (perpendicular to the bone), the convention of the tables: the pegs of
:func:`~.landmarks.marker_pegs` stand along that normal and :func:`~.landmarks.landmark_depths`
measures along it (the normal of the bone's outer face around the landmark,
:func:`~.landmarks.exposed_normals`, so that the rim of an opening is not measured into the opening).

**Codes.** The table uses Caple & Stephan's (2016) codes. :data:`CODE_MAP` maps them to the landmark
set of :mod:`.landmarks`; a bilateral code without a side (``zy``) means both sides. The set holds every
code of the table (``mn``, ``ss``, ``gn``, ``ac``, ``sC``, ``iC``, ``mr`` and ``mmb`` were added for it).
Landmarks of the set that the T-Table does not cover: :func:`uncovered_landmarks` (frontal eminence,
inferior malar, lateral orbit, supraglenoid, occlusal line, and porion and orbitale, which orient the
skull and carry no depth).
"""
from __future__ import annotations

import csv
import json
import os
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core.errors import PDEHeadError
from ..core.provenance import provenance_lines
from .landmarks import STANDARD_LANDMARKS, landmark

#: The shipped default table.
DEFAULT_TABLE_PATH = Path(__file__).resolve().parent / "data" / "t_table_2023.csv"

#: Caple & Stephan code -> (key of our landmark or None, bilateral, Caple & Stephan name).
CODE_MAP: dict[str, tuple[str | None, bool, str]] = {
    "op": ("op", False, "Opisthocranion"),
    "v": ("v", False, "Vertex"),
    "g": ("g", False, "Glabella"),
    "n": ("n", False, "Nasion"),
    "mn": ("mn", False, "Midnasale"),
    "rhi": ("rhi", False, "Rhinion"),
    "ss": ("ss", False, "Subspinale"),
    "mp": ("mp", False, "Mid-philtrum"),
    "pr": ("sd", False, "Prosthion"),            # our Supradentale: the upper alveolar crest between the incisors
    "id": ("id", False, "Infradentale"),
    "sm": ("sm", False, "Supramentale"),
    "pg": ("pog", False, "Pogonion"),
    "gn": ("gn", False, "Gnathion"),
    "me": ("me", False, "Menton"),
    "mso": ("so", True, "Mid-supraorbital"),
    "mio": ("sbo", True, "Mid-infraorbital"),
    "ac": ("ac", True, "Alar curvature"),
    "go": ("go", True, "Gonion"),
    "zy": ("za", True, "Zygion"),
    "sc": ("sc", True, "Supracanine"),
    "ic": ("ic", True, "Infracanine"),
    "ecm2(s)": ("supm2", True, "Ectomolare superior (above M2)"),
    "ecm2(i)": ("subm2", True, "Ectomolare inferior (below M2)"),
    "mr": ("mr", True, "Mid-ramus"),
    "mmb": ("mmb", True, "Mid-mandibular border"),
}
#: Other spellings of codes (the soft-tissue names of the ectomolare pairs).
CODE_ALIASES = {"sm2": "ecm2(s)", "im2": "ecm2(i)", "ecm2s": "ecm2(s)", "ecm2i": "ecm2(i)", "zyg": "zy"}
#: The values of a depth table's ``sex`` column (besides ``pooled``, or empty: both sexes).
SEXES = ("male", "female")
#: Other spellings of the ``sex`` column's values.
SEX_ALIASES = {"m": "male", "f": "female", "men": "male", "women": "female", "": "pooled", "all": "pooled",
               "both": "pooled"}
_SIDE = re.compile(r"^(?P<code>.+?)[\s_\-]*(?P<side>[LRlr])$")


@dataclass(frozen=True)
class DepthEntry:
    """One landmark's depth: mean and SD (mm), sample size, the table's code for it."""

    landmark: str
    mean_mm: float
    sd_mm: float | None = None
    n: int | None = None
    code: str | None = None

    def range_mm(self, k: float = 2.0) -> tuple[float, float]:
        """mean - k SD .. mean + k SD (never below 0); (mean, mean) without an SD."""
        if self.sd_mm is None:
            return self.mean_mm, self.mean_mm
        return max(0.0, self.mean_mm - k * self.sd_mm), self.mean_mm + k * self.sd_mm


@dataclass
class DepthTable(Mapping):
    """A depth table: landmark name -> mean depth (mm), as a read-only mapping, plus SDs and provenance.

    ``table[name]`` is the mean (so code written for plain ``{name: depth}`` dicts keeps working);
    :attr:`entries` holds the :class:`DepthEntry` with SD and n.
    """

    entries: dict[str, DepthEntry] = field(default_factory=dict)
    name: str = ""
    version: str = ""
    citation: str = ""
    provenance: str = ""
    convention: str = ""
    source: str = ""
    #: Every row of a table with a ``sex`` column: ``"male"`` / ``"female"`` / ``"pooled"`` -> landmark -> entry
    #: (empty for a pooled table). :attr:`entries` are the pooled rows, or one sex's after :meth:`for_sex`.
    by_sex: dict[str, dict[str, DepthEntry]] = field(default_factory=dict)
    #: The sex whose rows :attr:`entries` are ("" : pooled).
    sex: str = ""

    def __getitem__(self, key: str) -> float:
        return self.entries[key].mean_mm

    def __iter__(self):
        return iter(self.entries)

    def __len__(self) -> int:
        return len(self.entries)

    def sd(self, key: str) -> float | None:
        return self.entries[key].sd_mm

    @property
    def label(self) -> str:
        """``name`` and ``version`` as one short label (e.g. for the ``table_name`` column), and the sex whose
        rows are used."""
        text = f"{self.name} v{self.version}" if self.version and self.version not in self.name else self.name
        return f"{text}, {self.sex}" if self.sex else text

    @property
    def sexes(self) -> tuple[str, ...]:
        """The sexes the table has rows for (``()``: a pooled table)."""
        return tuple(sex for sex in SEXES if sex in self.by_sex)

    def for_sex(self, sex: str | None) -> "DepthTable":
        """The table with one sex's rows as its entries (``None`` / ``"pooled"``: the pooled rows).

        Raises
        ------
        PDEHeadError
            A sex the table has no rows for (a pooled table has none), or pooled rows asked of a table that
            gives its depths per sex only.
        """
        sex = (sex or "pooled").strip().lower()
        if not self.by_sex:                                   # a pooled table
            if sex == "pooled":
                return self
            raise PDEHeadError(f"the depth table '{self.name}' is pooled (it has no sex column): no {sex} values")
        rows = self.by_sex.get(sex)
        if not rows:
            if sex == "pooled":
                raise PDEHeadError(f"the depth table '{self.name}' gives its depths per sex only "
                                   f"({', '.join(self.sexes)}): choose one")
            raise PDEHeadError(f"the depth table '{self.name}' has rows for {', '.join(self.sexes)} only: "
                               f"no {sex} values")
        return replace(self, entries=dict(rows), sex="" if sex == "pooled" else sex)

    def provenance_record(self) -> dict:
        out = {"table": self.label, "table_citation": self.citation, "table_provenance": self.provenance,
               "table_convention": self.convention, "table_file": self.source}
        return {k: v for k, v in out.items() if v}

    def to_json(self) -> str:
        d = {k: getattr(self, k) for k in ("name", "version", "citation", "provenance", "convention", "source",
                                           "sex")}
        d["entries"] = [asdict(e) for e in self.entries.values()]
        if self.by_sex:
            d["by_sex"] = {sex: [asdict(e) for e in rows.values()] for sex, rows in self.by_sex.items()}
        return json.dumps(d)

    @classmethod
    def from_json(cls, text: str) -> "DepthTable":
        """The inverse of :meth:`to_json`; also accepts an old plain ``{name: depth}`` JSON dict."""
        d = json.loads(text or "{}")
        if "entries" not in d:
            return cls(entries={k: DepthEntry(k, float(v)) for k, v in d.items()}, name="imported table")
        def rows(items):
            return {e["landmark"]: DepthEntry(**e) for e in items}

        entries = rows(d.pop("entries"))
        by_sex = {sex: rows(items) for sex, items in d.pop("by_sex", {}).items()}
        return cls(entries=entries, by_sex=by_sex, **d)


def _code_key(text: str) -> str:
    c = text.strip().lower().replace(" ", "")
    return CODE_ALIASES.get(c, c)


def _our_name(key: str | None, fallback: str) -> str:
    """Our landmark's name for ``key`` (or a landmark named ``fallback``), else ``fallback`` itself."""
    for candidate in (key, fallback):
        if candidate:
            try:
                return landmark(candidate).name
            except PDEHeadError:
                pass
    return fallback


def resolve_landmark(text: str) -> list[str]:
    """The landmark name(s) a depth-table row means: ours by name or key, or a Caple & Stephan code.

    A bilateral code without a side gives both sides (``"zy"`` -> Zygomatic arch L and R); with one
    (``"zyL"``, ``"zy_l"``, ``"ecm2(s)R"``) one side. Codes our set lacks keep Caple & Stephan's names
    ("Midnasale", "Supracanine L", ...).

    Raises
    ------
    PDEHeadError
        Unknown name or code; a side on a midline code.
    """
    raw = str(text).strip()
    try:
        return [landmark(raw).name]
    except PDEHeadError:
        pass
    full_names = {v[2].lower(): k for k, v in CODE_MAP.items()}
    key = _code_key(raw)
    side = None
    if key not in CODE_MAP and key not in full_names:
        m = _SIDE.match(raw.strip())
        if m:
            base = _code_key(m.group("code"))
            if base in CODE_MAP or base in full_names:
                key, side = base, m.group("side").upper()
    code = key if key in CODE_MAP else full_names.get(key)
    if code is None:
        known = ", ".join(CODE_MAP)
        raise PDEHeadError(f"unknown landmark {raw!r}: neither a landmark of the standard set "
                           f"({', '.join(d.name for d in STANDARD_LANDMARKS[:6])}, ...) nor a depth-table code "
                           f"({known})")
    ours, bilateral, cs_name = CODE_MAP[code]
    if not bilateral:
        if side:
            raise PDEHeadError(f"landmark {raw!r}: {code} is a midline landmark (no side)")
        return [_our_name(ours, cs_name)]
    sides = [side] if side else ["L", "R"]
    return [_our_name(f"{ours}_{s.lower()}" if ours else None, f"{cs_name} {s}") for s in sides]


def _number(text: str, what: str, where: str, low: float = 0.0, high: float = 100.0) -> float | None:
    text = (text or "").strip()
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        raise PDEHeadError(f"{where}: {what} {text!r} is not a number") from None
    if not (np.isfinite(value) and low <= value < high):
        raise PDEHeadError(f"{where}: {what} {value:g} is outside {low:g}..{high:g}")
    return value


def _cell(row: list[str], i: int | None) -> str:
    """Column ``i`` of a CSV row, "" when the column is absent (``i`` None) or the row is shorter."""
    return row[i] if i is not None and i < len(row) else ""


def read_depth_table(path: str | os.PathLike) -> DepthTable:
    """Read a depth table CSV.

    Columns ``landmark,mean_mm[,sd_mm,n]`` (the T-Table layout) or the older ``landmark,depth_mm``;
    an optional ``sex`` column (``male``, ``female``, or ``pooled`` / empty) gives depths per sex
    (:attr:`DepthTable.by_sex`, chosen with :meth:`DepthTable.for_sex`); further columns are ignored.
    Landmark names may be ours (name or key, case-insensitive) or the table's Caple & Stephan codes
    (:func:`resolve_landmark`). ``#`` lines are comments; ``# name:``, ``# version:``, ``# citation:``,
    ``# provenance:`` and ``# convention:`` lines give the table's provenance (the name defaults to the
    file's stem).

    Raises
    ------
    PDEHeadError
        Unreadable file, no ``landmark`` and ``mean_mm``/``depth_mm`` columns, an unknown landmark, a
        landmark given twice for the same sex, an unknown sex, or a bad number - naming the file and the line.
    """
    path = os.fspath(path)
    meta: dict[str, str] = {}
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = []
            for i, row in enumerate(csv.reader(fh)):
                if not row or not "".join(row).strip():
                    continue
                if row[0].lstrip().startswith("#"):
                    m = re.match(r"#\s*(name|version|citation|provenance|convention)\s*:\s*(.*)$",
                                 ",".join(row).strip())
                    if m:
                        meta[m.group(1)] = m.group(2).strip()
                    continue
                rows.append((i + 1, row))
    except OSError as exc:
        raise PDEHeadError(f"{path}: cannot read the depth table ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise PDEHeadError(f"{path}: not a text CSV file") from None
    if not rows:
        raise PDEHeadError(f"{path}: the depth table is empty")
    header = [h.strip().lower() for h in rows[0][1]]
    mean_col = "mean_mm" if "mean_mm" in header else "depth_mm" if "depth_mm" in header else None
    if "landmark" not in header or mean_col is None:
        raise PDEHeadError(f"{path}: a depth table needs the columns 'landmark' and 'mean_mm' (or 'depth_mm'), "
                           f"got {rows[0][1]}")
    li, mi = header.index("landmark"), header.index(mean_col)
    si = header.index("sd_mm") if "sd_mm" in header else None
    ni = header.index("n") if "n" in header else None
    xi = header.index("sex") if "sex" in header else None
    by_sex: dict[str, dict[str, DepthEntry]] = {}
    for number, row in rows[1:]:
        where = f"{path}, line {number}"
        try:
            names = resolve_landmark(_cell(row, li))
        except PDEHeadError as exc:
            raise PDEHeadError(f"{where}: {exc}") from None
        mean = _number(_cell(row, mi), mean_col.replace("_mm", ""), where)
        if mean is None:
            raise PDEHeadError(f"{where}: no {mean_col} value for {_cell(row, li).strip()!r}")
        sd = _number(_cell(row, si), "sd", where, 0.0, 50.0)
        n = _number(_cell(row, ni), "n", where, 1.0, 1e9)
        sex = _cell(row, xi).strip().lower()
        sex = SEX_ALIASES.get(sex, sex)
        if sex not in (*SEXES, "pooled"):
            raise PDEHeadError(f"{where}: sex {_cell(row, xi).strip()!r} is not one of male, female, pooled")
        rows_of = by_sex.setdefault(sex, {})
        for name in names:
            if name in rows_of:
                raise PDEHeadError(f"{where}: {name} is given twice" + ("" if sex == "pooled" else f" for {sex}"))
            rows_of[name] = DepthEntry(name, mean, sd, None if n is None else int(n), _cell(row, li).strip())
    return DepthTable(entries=dict(by_sex.get("pooled", {})), name=meta.get("name") or Path(path).stem,
                      version=meta.get("version", ""), citation=meta.get("citation", ""),
                      provenance=meta.get("provenance", ""),
                      convention=meta.get("convention", ""), source=os.path.basename(path),
                      **({"by_sex": by_sex} if xi is not None else {}))


def default_table() -> DepthTable:
    """The shipped T-Table 2023 (:data:`DEFAULT_TABLE_PATH`), with its citation and provenance."""
    return read_depth_table(DEFAULT_TABLE_PATH)


def uncovered_landmarks(table: DepthTable | None = None) -> list[str]:
    """Landmarks of the standard set that ``table`` (default: the shipped one) has no depth for."""
    table = default_table() if table is None else table
    return [d.name for d in STANDARD_LANDMARKS if d.name not in table]


def clamp_to_table(table: DepthTable, name: str, value: float, k: float = 2.0) -> float:
    """``value`` limited to the table's mean +- k SD for ``name`` (a peg length a user may choose)."""
    lo, hi = table.entries[name].range_mm(k)
    return float(min(max(value, lo), hi))


# --------------------------------------------------------------------------- landmarks.csv
LANDMARK_COLUMNS = ["landmark", "x_mm", "y_mm", "z_mm", "depth_mm", "table_mm", "table_name", "sd_mm", "flag"]
#: Flags of a landmark: placed by hand or found with good evidence, weak evidence, not found.
FLAGS = ("ok", "uncertain", "not_found")


def write_landmark_csv(path: str | os.PathLike, depths: dict[str, tuple[np.ndarray, float]],
                       table: Mapping | None = None, flags: dict[str, str] | None = None,
                       provenance: dict | None = None) -> int:
    """Write ``landmarks.csv``; returns the number of landmark rows.

    Columns :data:`LANDMARK_COLUMNS`: the landmark, its bone point in the CT's patient frame (LPS mm;
    never the Frankfurt-aligned one), the measured depth along the bone normal (mm), the table's
    mean, the table's name and SD, and the flag (``ok`` for hand-placed landmarks unless ``flags``
    says otherwise). Empty where unknown. ``provenance`` (software, table, bone level, ...) goes
    first as ``# key: value`` lines.
    """
    path = os.fspath(path)
    table = table or {}
    label = table.label if isinstance(table, DepthTable) else ("imported table" if table else "")
    flags = flags or {}
    try:
        with open(path, "w", newline="") as fh:
            for line in provenance_lines(provenance):
                fh.write(line + "\n")
            w = csv.writer(fh)
            w.writerow(LANDMARK_COLUMNS)
            for name, (p, d) in depths.items():
                entry = table.entries.get(name) if isinstance(table, DepthTable) else None
                ref = table.get(name) if not isinstance(table, DepthTable) else (entry.mean_mm if entry else None)
                sd = entry.sd_mm if entry is not None else None
                flag = flags.get(name, "ok")
                if flag not in FLAGS:
                    raise PDEHeadError(f"landmark {name}: flag {flag!r} is not one of {', '.join(FLAGS)}")
                w.writerow([name, *("" if not np.isfinite(c) else f"{c:.3f}" for c in p),
                            "" if not np.isfinite(d) else f"{d:.3f}",
                            "" if ref is None else f"{ref:g}", label if ref is not None else "",
                            "" if sd is None else f"{sd:g}", flag])
    except OSError as exc:
        raise PDEHeadError(f"{path}: cannot write ({exc.strerror})") from None
    return len(depths)
