"""Collect every problem of a scenario file and report them in one message."""

import difflib
from typing import Any, NamedTuple

from .schema import SECTIONS, TOP_LEVEL_KEYS, Table


class Problem(NamedTuple):
    table: str  # e.g. "[[bodies]] #2 (left)", "[initial.beam]"
    key: str  # e.g. "mass", "angles.degrees", "" for the whole table
    message: str


class ScenarioError(ValueError):
    """A scenario file is invalid; `.problems` lists every problem found, each with
    its table, key and message, and `str(error)` names the file and all of them."""

    what = "scenario file"

    def __init__(self, source: str, problems: list[Problem]):
        self.source = str(source)
        self.problems = list(problems)
        super().__init__(format_problems(self.source, self.problems, self.what))


def format_problems(
    source: str, problems: list[Problem], what: str = "scenario file"
) -> str:
    n = len(problems)
    lines = [f"{source}: {n} problem{'s' if n != 1 else ''} in the {what}:"]
    for p in problems:
        if p.table == "(file)":
            lines.append(f"  - {p.message}")
            continue
        where = f"table {p.table}" + (f", key '{p.key}'" if p.key else "")
        lines.append(f"  - {where}: {p.message}")
    return "\n".join(lines)


def _all_field_names() -> list[str]:
    names = set(SECTIONS) | set(TOP_LEVEL_KEYS)
    tables = [Table]
    while tables:
        table = tables.pop()
        names |= set(table.model_fields)
        tables += table.__subclasses__()
    return sorted(names)


def unknown_key_message(key, allowed=None) -> str:
    """'unknown key' with a did-you-mean suggestion from the schema's key names."""
    candidates = list(allowed) if allowed is not None else _all_field_names()
    # (a key of another table is unknown here, not a misspelling of itself)
    candidates = [name for name in candidates if name != str(key)]
    close = difflib.get_close_matches(str(key), candidates, n=1)
    return "unknown key" + (f" (did you mean '{close[0]}'?)" if close else "")


def show_value(value) -> str:
    """A value for a message, kept short: a long integer by its number of digits, a
    large table or array by its type."""
    if isinstance(value, int) and not isinstance(value, bool):
        digits = len(str(abs(value)))
        if digits > 24:
            return f"{'a negative' if value < 0 else 'an'} integer of {digits} digits"
        return repr(value)
    if isinstance(value, dict | list) and len(str(value)) > 60:
        return type(value).__name__
    return repr(value)


def message_of(err: dict) -> str:
    """The message of one pydantic error, meant to follow "table [...], key ...: "."""
    kind = err["type"]
    value = err.get("input")
    if kind == "missing":
        return "missing required key"
    if kind == "extra_forbidden":
        return unknown_key_message(err["loc"][-1] if err["loc"] else "")
    if kind == "float_type" and isinstance(value, int) and not isinstance(value, bool):
        # an integer beyond the range of float64
        return (
            f"number too large: {show_value(value)} lies beyond the float64 range "
            f"(about ±1.8e308)"
        )
    msg = err["msg"]
    if msg.startswith("Value error, "):
        return msg[len("Value error, ") :]
    msg = msg.replace(" after validation", "")
    return f"{msg[0].lower()}{msg[1:]} (got {show_value(value)})"


def locate(
    section: str, shape: str, raw, loc: tuple[Any, ...] | list[Any]
) -> tuple[str, str]:
    """Table and key of a pydantic error location within one top-level section.

    Leading locations whose raw value is a TOML table become the table path
    (`[forces.pose_tracking]`); the rest is the key (`kp[2]`).
    """
    loc = list(loc)
    if shape == "array":
        if loc and isinstance(loc[0], int):
            k = loc.pop(0)
            entry = raw[k] if isinstance(raw, list) and k < len(raw) else None
            name = entry.get("name") if isinstance(entry, dict) else None
            label = f" ({name})" if isinstance(name, str) else ""
            table, node = f"[[{section}]] #{k + 1}{label}", entry
        else:
            table, node = f"[[{section}]]", raw
        path = []
    else:
        table, path, node = None, [section], raw
    while len(loc) > 1 and isinstance(loc[0], str) and isinstance(node, dict):
        nxt = node.get(loc[0])
        if not isinstance(nxt, dict):
            break
        path.append(loc.pop(0))
        node = nxt
    if table is None:
        table = "[" + ".".join(path) + "]"
    elif path:
        table = table + "." + ".".join(path)
    key = ""
    for part in loc:
        if isinstance(part, int):
            key += f"[{part}]"
        else:
            key += ("." if key else "") + str(part)
    return table, key


class Problems:
    """A list of problems for one file; `raise_if_any` raises them as `error` (a
    `ScenarioError` class: the scenario's, or one for another kind of file)."""

    def __init__(self, source: str, error: type[ScenarioError] = ScenarioError):
        self.source = str(source)
        self.error = error
        self.items: list[Problem] = []

    def add(self, table: str, key: str, message: str) -> None:
        self.items.append(Problem(table, key, message))

    def add_validation_error(self, section, shape, raw, error, prefix=()) -> None:
        for err in error.errors():
            table, key = locate(section, shape, raw, (*prefix, *err["loc"]))
            self.add(table, key, message_of(err))

    def raise_if_any(self) -> None:
        if self.items:
            raise self.error(self.source, self.items)

    def __bool__(self):
        return bool(self.items)


class DataProblem(NamedTuple):
    """One problem of a measured-data file: the column (`""` for none) and the
    line of a CSV file or sample of a netCDF file (`""` for none) it lies in."""

    column: str
    row: str  # e.g. "line 7", "sample 12 (t = 0.11 s)"
    message: str


class DataFileError(ScenarioError):
    """A measured-data file is invalid; `.problems` lists every problem found
    (`DataProblem`: column, row and message), and `str(error)` names the file and
    all of them."""

    def __init__(self, source: str, problems: list[DataProblem]):
        self.source = str(source)
        self.problems = list(problems)  # type: ignore[arg-type]
        ValueError.__init__(self, format_data_problems(self.source, problems))


def format_data_problems(source: str, problems: list[DataProblem]) -> str:
    n = len(problems)
    lines = [f"{source}: {n} problem{'s' if n != 1 else ''} in the data file:"]
    for p in problems:
        where = ", ".join(
            part for part in (f"column '{p.column}'" if p.column else "", p.row) if part
        )
        lines.append(f"  - {where}: {p.message}" if where else f"  - {p.message}")
    return "\n".join(lines)
