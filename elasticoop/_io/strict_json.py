"""JSON text that every parser accepts: non-finite numbers become `null`.

Python's `json` writes NaN and infinity as the bare words `NaN` and `Infinity`,
which are not JSON (RFC 8259): strict parsers (JavaScript's `JSON.parse`, `jq`,
Python's own with `parse_constant` raising) refuse the whole file.
"""

import json
import math
from typing import Any

import numpy as np


def json_ready(value: Any) -> Any:
    """`value` with every non-finite float (NaN, +-inf) replaced by `None`, numpy
    scalars and arrays turned into Python numbers and lists, tuples into lists;
    dictionaries and lists are converted item by item."""
    if isinstance(value, dict):
        return {key: json_ready(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(item) for item in value]
    if isinstance(value, np.ndarray | np.generic):
        return json_ready(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def strict_json(value: Any) -> str:
    """`value` as indented JSON text ending in a newline, with non-finite numbers
    written as `null` (see `json_ready`)."""
    return json.dumps(json_ready(value), indent=2, allow_nan=False) + "\n"
