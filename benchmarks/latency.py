"""Latency in fresh processes: the command line's answers, and the first call of
the default scenario.

    python benchmarks/latency.py [--json out.json]

The command line: wall time of `python -m elasticoop --version`, `--help` and
`check` of the built-in scenario file (its static equilibrium's traced program
and compiled code are stored: warm, with the cache folder a first `check` filled),
each the quickest of `repeats` fresh processes.

Wall time of `python -c` importing elasticoop and simulating
`default_scenario()` (3 bodies, 2 grasps, 3 s, Tsit5 at rtol 1e-8), first and second
call, in fresh processes: without the persistent compilation cache, with an
empty cache (cold) and with the cache it filled (warm); two rounds of the three in
turn, each row the quicker of its two (a process's first seconds are at the mercy
of a shared machine).

`python benchmarks/latency.py --command-line` times the command line alone.
"""

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

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


SCENARIO = Path(__file__).resolve().parents[1] / "elasticoop/scenarios/beam_lift.toml"
COMMANDS = {
    "--version": ["--version"],
    "--help": ["--help"],
    "check (warm)": ["check", str(SCENARIO)],
}
TARGETS_S = {"--version": 0.5, "--help": 1.0, "check (warm)": 2.0}


def _command_s(arguments: list[str], env: dict) -> float:
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "elasticoop", *arguments],
        check=True,
        capture_output=True,
        env=env,
    )
    return time.perf_counter() - start


def command_line(repeats: int = 5, commands=tuple(COMMANDS)) -> dict:
    """Wall time of each command in fresh processes (the quickest and slowest of
    `repeats`), with a compilation cache of its own that a first run fills."""
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        env = {**os.environ, "ELASTICOOP_CACHE_DIR": folder}
        for name in commands:
            _command_s(COMMANDS[name], env)  # fills the cache; loads the files
            times = [_command_s(COMMANDS[name], env) for _ in range(repeats)]
            rows.append(
                {
                    "command": "python -m elasticoop " + " ".join(COMMANDS[name]),
                    "quickest_s": min(times),
                    "slowest_s": max(times),
                    "target_s": TARGETS_S[name],
                }
            )
    return {"problem": f"fresh processes, the quickest of {repeats}", "rows": rows}


def run(quick: bool = False, rounds: int = 2) -> dict:
    if quick:  # fresh processes compiling take tens of seconds: not at smoke size
        return {
            "problem": "command line only at smoke size (fresh processes)",
            "command_line": command_line(1, ("--version", "--help")),
        }
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
        "command_line": command_line(),
        "problem": "default_scenario(): 3 bodies, 2 grasps, 3 s, Tsit5 rtol 1e-8; "
        f"a fresh python process per run, the quickest of {rounds} per row",
        "rows": rows,
        "target": "process_s <= 5 s without the cache, <= 3 s with a warm cache",
    }


if __name__ == "__main__":
    if sys.argv[1:] == ["--command-line"]:
        print(json.dumps(command_line(), indent=2))
    else:
        from _cli import main

        main(run, __doc__)
