"""`python benchmarks/<name>.py [--quick] [--json FILE]` for one benchmark module."""

import argparse
import json


def main(run, doc: str) -> None:
    parser = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke-test sizes")
    parser.add_argument("--json", help="write the results to this file")
    args = parser.parse_args()
    result = run(quick=args.quick)
    print(json.dumps(result, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)
