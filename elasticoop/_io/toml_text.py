"""TOML text of a parsed scenario file (the standard library reads TOML but does
not write it): tables as `[a.b]` sections, arrays of tables as `[[a]]`, and tables
inside those as inline tables. Values are the types `tomllib` returns: strings,
booleans, integers, finite floats, lists and dictionaries."""

import json
import math
import re

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def toml_text(document: dict, header: str = "") -> str:
    """`document` (as `tomllib.loads` returns it) as TOML text, after the comment
    lines of `header`."""
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    _table(document, [], lines)
    return "\n".join(lines).strip("\n") + "\n"


def _key(key: str) -> str:
    return key if _BARE_KEY.match(key) else json.dumps(key)


def _is_table_array(value) -> bool:
    return (
        isinstance(value, list)
        and bool(value)
        and all(isinstance(v, dict) for v in value)
    )


def _is_section(value) -> bool:
    """A dictionary written as its own `[section]`: one holding further tables
    (`[initial]` holds one per body) or arrays of tables, or more than a few
    entries."""
    return isinstance(value, dict) and (
        any(isinstance(v, dict) or _is_table_array(v) for v in value.values())
        or len(value) > 2
    )


def _table(table: dict, path: list[str], lines: list[str]) -> None:
    simple = {
        k: v
        for k, v in table.items()
        if not (
            _is_section(v) or _is_table_array(v) or (not path and isinstance(v, dict))
        )
    }
    for key, value in simple.items():
        lines.append(f"{_key(key)} = {value_text(value)}")
    for key, value in table.items():
        if key in simple:
            continue
        here = [*path, _key(key)]
        if _is_table_array(value):
            for entry in value:
                lines += ["", f"[[{'.'.join(here)}]]"]
                for k, v in entry.items():
                    lines.append(f"{_key(k)} = {value_text(v)}")
            continue
        inner = {k: v for k, v in value.items() if not _is_section(v)}
        if inner or not value:
            lines += ["", f"[{'.'.join(here)}]"]
        for k, v in inner.items():
            lines.append(f"{_key(k)} = {value_text(v)}")
        rest = {k: v for k, v in value.items() if k not in inner}
        for k, v in rest.items():
            _table({k: v}, here, lines)


def value_text(value) -> str:
    """One TOML value; dictionaries become inline tables."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(
                f"TOML files of elasticoop hold finite numbers, got {value}"
            )
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list):
        return "[" + ", ".join(value_text(v) for v in value) + "]"
    if isinstance(value, dict):
        items = ", ".join(f"{_key(k)} = {value_text(v)}" for k, v in value.items())
        return "{ " + items + " }" if items else "{}"
    raise TypeError(f"no TOML form for {type(value).__name__}")
