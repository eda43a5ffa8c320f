"""Provenance of forensic outputs: which software, depth table and bone level made a file.

Every forensic output (the meshes for printing, ``tissue_depth.csv``, ``landmarks.csv``) carries
these lines in its header (CSV ``#`` lines, the STL header, OBJ/PLY comments) and in
``provenance.json`` beside it, so a result handed on can always be traced back.
"""
from __future__ import annotations

#: The engine's version (``pdehead_addon.__version__`` is this).
SOFTWARE_VERSION = "0.1.0"
SOFTWARE = f"PDE Head {SOFTWARE_VERSION}"


def provenance(**fields) -> dict:
    """An ordered provenance record: ``software`` first, then the given fields (None values dropped)."""
    out = {"software": SOFTWARE}
    out.update({k: v for k, v in fields.items() if v is not None and v != ""})
    return out


def provenance_lines(record: dict | None, prefix: str = "# ") -> list[str]:
    """``record`` as ``# key: value`` lines (newlines in values folded into spaces)."""
    if not record:
        return []
    return [f"{prefix}{k}: {' '.join(str(v).split())}" for k, v in record.items()]


#: The few non-ASCII characters of the provenance (the label's em dash, degrees, +-) spelt in ASCII, for the
#: headers that are ASCII (STL, PLY).
ASCII_SPELLING = str.maketrans({"\u2014": "-", "\u2013": "-", "\u00b1": "+-", "\u00b0": " deg", "\u00d7": "x"})


def ascii_text(text: str) -> str:
    """``text`` spelt in ASCII (:data:`ASCII_SPELLING`; any other non-ASCII character becomes ``?``)."""
    return str(text).translate(ASCII_SPELLING).encode("ascii", "replace").decode("ascii")


def short_provenance(record: dict | None, limit: int = 80, part: str | None = None) -> str:
    """One short ASCII line (for the 80-byte STL header), cut to ``limit``.

    The record's ``label`` comes first (a face from the skull: "approximation - not an identification" must
    survive the cut), then ``part`` (what the file is), then as much provenance as fits: software, bone
    level, table.
    """
    if not record:
        return ascii_text("; ".join(p for p in (part, SOFTWARE) if p))[:limit]
    parts = [str(record["label"])] if record.get("label") else []
    if part:
        parts.append(part)
    parts.append(str(record.get("software", SOFTWARE)))
    if record.get("bone_level") is not None:
        parts.append(f"bone {record['bone_level']}")
    if record.get("table"):
        parts.append(str(record["table"]))
    return ascii_text("; ".join(parts))[:limit]
