"""A small TOML writer for the flat tables this project writes (no extra dependency).

Python 3.11 reads TOML with :mod:`tomllib` but cannot write it; the files we write
(``calibration.toml``, ``scene.toml``, ``wand.toml``) only hold tables of strings,
numbers, booleans and (nested) lists of numbers, which this module covers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        esc = v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
        return f'"{esc}"'
    if hasattr(v, "tolist"):
        return _value(v.tolist())
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if hasattr(v, "item"):
        return _value(v.item())
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps(data: Mapping) -> str:
    """Serialise a mapping of scalars and one level of sub-tables to TOML text."""
    lines: list[str] = []
    tables = []
    for key, v in data.items():
        if isinstance(v, Mapping):
            tables.append((key, v))
        else:
            lines.append(f"{key} = {_value(v)}")
    for key, table in tables:
        if lines:
            lines.append("")
        lines.append(f"[{key}]")
        sub = []
        for k2, v2 in table.items():
            if isinstance(v2, Mapping):
                sub.append((k2, v2))
            else:
                lines.append(f"{k2} = {_value(v2)}")
        for k2, t2 in sub:
            lines.append("")
            lines.append(f"[{key}.{k2}]")
            for k3, v3 in t2.items():
                lines.append(f"{k3} = {_value(v3)}")
    return "\n".join(lines) + "\n"


def dump(data: Mapping, path: str | Path) -> None:
    """Write ``data`` as TOML to ``path`` (UTF-8)."""
    Path(path).write_text(dumps(data), encoding="utf-8")
