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


def short_provenance(record: dict | None, limit: int = 80) -> str:
    """One short line (for the 80-byte STL header): software, bone level, table; cut to ``limit``."""
    if not record:
        return SOFTWARE[:limit]
    parts = [str(record.get("software", SOFTWARE))]
    if record.get("bone_level") is not None:
        parts.append(f"bone {record['bone_level']}")
    if record.get("table"):
        parts.append(str(record["table"]))
    return "; ".join(parts)[:limit]
