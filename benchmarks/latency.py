"""First-call latency of the default scenario in fresh processes.

    python benchmarks/latency.py [--json out.json]

Wall time of `python -c` importing elasticoop and simulating
`default_scenario()` (3 bodies, 2 grasps, 3 s, Tsit5 at rtol 1e-8), first and second
call, in fresh processes: without the persistent compilation cache, with an
empty cache (cold) and with the cache it filled (warm); two rounds of the three in
turn, each row the quicker of its two (a process's first seconds are at the mercy
of a shared machine: one run of the first row measured 5.6 s against 4.6-4.9 s).
"""

import json
import os
import subprocess
import sys
import tempfile

_CHILD = r"""
import json, sys, time
start = time.perf_counter()
import jax
import elasticoop as eo
from elasticoop._cache import enable_compilation_cache
from elasticoop import default_scenario
if sys.argv[1] != "none":
    enable_compilation_cache(sys.argv[1])
imported = time.perf_counter()
s = default_scenario()
def once():
    t = time.perf_counter()
    traj = eo.simulate(s.model, s.y_init, s.ydot_init, s.ts, forces=s.forces)
    jax.block_until_ready(traj.y)
    return time.perf_counter() - t
first = once()
second = once()
print(json.dumps({"import_s": imported - start, "first_call_s": first,
                  "second_call_s": second,
                  "process_s": time.perf_counter() - start}))
"""


def _fresh_process(cache: str) -> dict:
    # JAX reads its own cache settings from the environment: the child uses only
    # the cache it is given (or none).
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION")}
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, cache],
        check=True,
        capture_output=True,
        text=True,
        env=env,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(quick: bool = False, rounds: int = 2) -> dict:
    if quick:  # fresh processes take tens of seconds: not at smoke size
        return {"problem": "skipped at smoke size (fresh processes)"}
    runs: dict[str, list[dict]] = {"off": [], "cold (empty)": [], "warm": []}
    for _ in range(rounds):  # in turn, so that a slow spell hits every row alike
        with tempfile.TemporaryDirectory() as folder:
            runs["off"].append(_fresh_process("none"))
            runs["cold (empty)"].append(_fresh_process(folder))
            runs["warm"].append(_fresh_process(folder))
    rows = [
        {
            "cache": cache,
            **min(found, key=lambda r: r["process_s"]),
            "slowest_process_s": max(r["process_s"] for r in found),
        }
        for cache, found in runs.items()
    ]
    return {
        "problem": "default_scenario(): 3 bodies, 2 grasps, 3 s, Tsit5 rtol 1e-8; "
        f"a fresh python process per run, the quickest of {rounds} per row",
        "rows": rows,
        "target": "process_s <= 5 s without the cache, <= 3 s with a warm cache",
    }


if __name__ == "__main__":
    from _cli import main

    main(run, __doc__)
