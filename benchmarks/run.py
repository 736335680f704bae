"""Run every benchmark in this folder, print a table, write JSON.

    python benchmarks/run.py [--quick] [--json out.json] [--only NAME ...]

A benchmark is a module here exposing `run(quick: bool) -> dict`; results are
collected under the module's name, with the machine and the wall time of each.
`--quick` runs the smoke-test sizes (no figure is meaningful there).
"""

import argparse
import importlib
import json
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

# Run first, in this order; any other module with `run` follows alphabetically.
ORDER = ("rhs", "scaling", "work_precision", "gradients", "latency")


def discover() -> list[str]:
    names = [p.stem for p in HERE.glob("*.py") if not p.stem.startswith("_")]
    names = [n for n in names if n != "run"]
    found = []
    for name in sorted(
        names, key=lambda n: (n not in ORDER, ORDER.index(n) if n in ORDER else 0, n)
    ):
        source = (HERE / f"{name}.py").read_text()
        if "\ndef run(" in source:
            found.append(name)
    return found


def _format(value) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    if value is None:
        return "-"
    return str(value)


def _tables(result, title, out):
    """Print every list of row dicts found in `result` as a table."""
    if isinstance(result, dict):
        scalars = {k: v for k, v in result.items() if not isinstance(v, dict | list)}
        if scalars:
            out.append(
                f"{title}: "
                + ", ".join(f"{k} = {_format(v)}" for k, v in scalars.items())
            )
        for key, value in result.items():
            if key == "rows" and isinstance(value, list) and value:
                cols = list(dict.fromkeys(k for row in value for k in row))
                cells = [[_format(row.get(c)) for c in cols] for row in value]
                widths = [
                    max(len(c), *(len(r[i]) for r in cells)) for i, c in enumerate(cols)
                ]
                out.append("  " + "  ".join(c.rjust(w) for c, w in zip(cols, widths)))
                for r in cells:
                    out.append("  " + "  ".join(x.rjust(w) for x, w in zip(r, widths)))
            elif isinstance(value, dict):
                _tables(value, f"{title}.{key}", out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke-test sizes")
    parser.add_argument("--json", help="write all results to this file")
    parser.add_argument("--only", nargs="*", help="run only these benchmarks")
    args = parser.parse_args(argv)

    from _timing import machine

    names = discover()
    if args.only:
        names = [n for n in names if n in args.only]
    results = {"machine": machine(), "quick": args.quick, "benchmarks": {}}
    failed = False
    for name in names:
        print(f"== {name}", flush=True)
        start = time.perf_counter()
        try:
            result = importlib.import_module(name).run(quick=args.quick)
        except Exception:
            failed = True
            result = {"error": traceback.format_exc(limit=3)}
        result["wall_s"] = time.perf_counter() - start
        results["benchmarks"][name] = result
        lines = []
        _tables(result, name, lines)
        print("\n".join(lines), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
        print(f"results written to {args.json}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
