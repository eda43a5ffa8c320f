"""Messages in the language of where they are shown: Python arguments, CLI flags, dialog fields.

The engine's errors and warnings name its own keyword arguments, always written
``name=value`` (``first_slice='inferior'``, ``spacing=(dz, dy, dx)``, ``dtype='>i2'``), so a
Python user can paste them. The command line (``scripts/pdehead.py``) and the import dialog show
the same messages through :func:`for_cli` and :func:`for_dialog`, which rewrite each ``name=value``
into the flag (``--first-slice inferior``) or the dialog's field (``First Slice: Inferior``).
One table (:data:`OPTIONS`) owns the correspondence.
"""
from __future__ import annotations

import re

#: engine argument -> (CLI flag, dialog field)
OPTIONS = {
    "first_slice": ("--first-slice", "First Slice"),
    "orientation": ("--orientation", "Orientation"),
    "spacing": ("--spacing", "Spacing (dz, dy, dx)"),
    "dtype": ("--dtype", "Data Type and Byte Order"),
    "byte_order": ("--dtype", "Byte Order"),
    "shape": ("--raw-shape", "Slice Shape"),
    "format": ("--format", "Format"),
    "units": ("--units", "Units"),
    "series_uid": ("--series-uid", "Series UID"),
    "downsample": ("--downsample", "Downsample"),
    "bone_level": ("--bone-level", "Bone Level"),
}
_DIALOG_DTYPES = {"i2": "int16", "u2": "uint16", "u1": "uint8", "i4": "int32", "f4": "float32"}
_VALUE = r"(?:'[^']*'|\"[^\"]*\"|\([^()]*\)|[A-Za-z0-9_.\-]+)"
_PATTERN = re.compile(r"\b(" + "|".join(OPTIONS) + r")=(" + _VALUE + r")?")


def _unquote(value: str) -> str:
    return value[1:-1] if len(value) >= 2 and value[0] == value[-1] and value[0] in "'\"" else value


def _numbers(value: str) -> list[str] | None:
    """'(2.0, 1.0, 1)' -> ['2', '1', '1']; '(dz, dy, dx)' -> ['DZ', 'DY', 'DX']; None if not a tuple."""
    if not (value.startswith("(") and value.endswith(")")):
        return None
    out = []
    for part in (p.strip() for p in value[1:-1].split(",") if p.strip()):
        try:
            out.append(f"{float(part):g}")
        except ValueError:
            out.append(part.upper())
    return out


def _cli(match: re.Match) -> str:
    name, value = match.group(1), match.group(2)
    flag = OPTIONS[name][0]
    if value is None:
        return flag
    parts = _numbers(value)
    if parts is not None:
        return f"{flag} {' '.join(parts)}"
    text = _unquote(value)
    if name == "dtype" or re.search(r"[<>|]", text):
        return f"{flag} '{text}'"
    if name == "byte_order":
        return f"{flag} '{'>' if text.lower().startswith('b') else '<'}...'"
    return f"{flag} {text}"


def _dialog(match: re.Match) -> str:
    name, value = match.group(1), match.group(2)
    field = OPTIONS[name][1]
    if value is None:
        return f"'{field}'"
    text = _unquote(value)
    if name == "dtype":
        order = {">": "Big Endian", "<": "Little Endian"}.get(text[:1], "")
        kind = _DIALOG_DTYPES.get(text.lstrip("<>|="), text)
        return f"'Data Type' {kind}" + (f" with 'Byte Order' {order}" if order else "")
    if name == "byte_order":
        return f"'Byte Order' {'Big Endian' if text.lower().startswith('b') else 'Little Endian'}"
    parts = _numbers(value)
    if parts is not None:
        return f"'{field}' {' x '.join(p.lower() for p in parts)}"
    if name in ("first_slice", "format", "units") and text.isalpha():
        text = text.capitalize() if text.lower() != "hu" else "HU"
    return f"'{field}' {text}"


def for_cli(message: str) -> str:
    """``message`` with every engine argument written as the CLI's flag, on one line."""
    return one_line(_PATTERN.sub(_cli, str(message)))


def for_dialog(message: str) -> str:
    """``message`` with every engine argument written as the import dialog's field ("pass" becomes "set")."""
    text = _PATTERN.sub(_dialog, str(message))
    text = re.sub(r"\bpass (?=')", "set ", text)
    return one_line(text)


def one_line(message: str) -> str:
    """Whitespace (newlines included) folded to single spaces; numbers rounded for people."""
    return round_numbers(" ".join(str(message).split()))


_LONG_NUMBER = re.compile(r"(?<![\w.])-?\d+\.\d{5,}(?:e[-+]?\d+)?(?![\w.])")


def round_numbers(text: str, digits: int = 4) -> str:
    """Decimals with 5 or more places (float32 noise such as 0.05000000074505806) to ``digits``
    significant digits: '0.05', '0.4883'."""
    return _LONG_NUMBER.sub(lambda m: f"{float(m.group()):.{digits}g}", text)
