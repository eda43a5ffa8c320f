"""Named sections of docs/benchmarks.md that separate benchmark scripts own.

Each benchmark writes its results between ``<!-- section:NAME -->`` and
``<!-- /section:NAME -->``; :func:`write_section` replaces its own section (or
appends it) and leaves the rest of the file as it is, and :func:`keep_sections`
lets a script that regenerates the whole file carry the other sections over.
"""
from __future__ import annotations

import re
from pathlib import Path

_SECTION = re.compile(r"<!-- section:(?P<name>[\w-]+) -->\n.*?<!-- /section:(?P=name) -->\n?", re.S)


def _block(name: str, text: str) -> str:
    return f"<!-- section:{name} -->\n{text.rstrip()}\n<!-- /section:{name} -->\n"


def sections(text: str) -> dict[str, str]:
    """The named sections in a markdown text, name -> whole block (markers included)."""
    return {m.group("name"): m.group(0) for m in _SECTION.finditer(text)}


def write_section(path: Path, name: str, text: str) -> None:
    """Replace (or append) section ``name`` of the markdown file at ``path``."""
    path = Path(path)
    old = path.read_text() if path.exists() else ""
    block = _block(name, text)
    if name in sections(old):
        new = _SECTION.sub(lambda m: block if m.group("name") == name else m.group(0), old)
    else:
        new = old.rstrip() + ("\n\n" if old.strip() else "") + block
    path.write_text(new)


def keep_sections(new_text: str, path: Path) -> str:
    """``new_text`` with the named sections of the file at ``path`` appended (those it does not have)."""
    path = Path(path)
    if not path.exists():
        return new_text
    have = sections(new_text)
    extra = [b for n, b in sections(path.read_text()).items() if n not in have]
    return new_text.rstrip() + "\n\n" + "\n".join(extra) if extra else new_text
