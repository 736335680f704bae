"""Where the test suite's time goes: JAX tracing, lowering and XLA compilation
against the tests' wall time, by test file and by compiled program.

    python benchmarks/suite_compilation.py [--json FILE] [pytest arguments ...]

runs `python -m pytest` (default arguments: `-n 2 -q -m slow`, the slow tier on two
workers) with this module as a plugin. Each process of the run (pytest-xdist's
workers included) switches on `jax_log_compiles`, whose log records say how long
each tracing (`Finished tracing ...`), lowering (`Finished jaxpr to MLIR module
conversion ...`) and XLA compilation (`Finished XLA compilation of ...`) took,
and writes them, with the test that was running, to a folder of its own. The
summary adds them up: the tests' time (the sum of their wall times over the
workers, "test-seconds") and the share of it spent tracing, lowering and
compiling. What the processes that tests start compile is in those tests' wall
time only; a program that the command line's compilation cache loads is logged
(and counted) as a compilation; what is compiled while collecting the tests
counts towards the share but not the tests' time. Not part of `run.py`: it times
the tests, not the library.

It also counts, per process, the distinct calls of `simulate`'s compiled program
(`_solve`: the structure, shapes, dtypes and static values of its arguments), and
how many stay distinct when a static setting is left out of the count (the
tolerances and thresholds, the number of output times, `max_steps`, or all of
them): the programs that taking such a setting as a run-time value would merge.
"""

import collections
import json
import logging
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

_FOLDER = "SUITE_COMPILATION_LOG"
_RECORD = re.compile(
    r"Finished (tracing|jaxpr to MLIR module conversion|XLA compilation)"
    r"(?: of)? (\S+).*? in ([0-9.eE+-]+) sec"
)
_KINDS = {
    "tracing": "tracing",
    "jaxpr to MLIR module conversion": "lowering",
    "XLA compilation": "compilation",
}


# ---- the plugin (loaded by `-p suite_compilation` in every pytest process) ----

_current = ["(collection)"]
_out: list = []
# `_solve`'s positional arguments left out of each count (see the docstring)
_SETTINGS = {
    "nothing": (),
    "tolerances": (6, 7, 11, 12),  # rtol, atol, gimbal_tol, link_tol
    "output times": (3,),  # ts
    "max_steps": (8,),
    "all of these": (3, 6, 7, 8, 11, 12),
}
_signatures: dict[str, set] = {name: set() for name in _SETTINGS}


def _signature(args: tuple, left_out: tuple) -> str:
    import jax

    def leaf(x):
        if hasattr(x, "shape") and hasattr(x, "dtype"):
            return (type(x).__name__, tuple(x.shape), str(x.dtype))
        if isinstance(x, (int, float, bool, str, type(None))):
            return repr(x)
        return type(x).__name__

    return repr(
        [
            None
            if i in left_out
            else (str(jax.tree.structure(a)), [leaf(x) for x in jax.tree.leaves(a)])
            for i, a in enumerate(args)
        ]
    )


def _count_solve_calls(folder: str, worker: str) -> None:
    import atexit
    import functools

    import elasticoop._simulate as simulate_module

    solve = simulate_module._solve

    # (`functools.wraps`: what the tests ask of `_solve`, such as its number of
    # traces, `eqx.debug.get_num_traces`, reaches the function wrapped)
    @functools.wraps(solve)
    def counted(*args, **kwargs):
        for name, left_out in _SETTINGS.items():
            _signatures[name].add(_signature(args, left_out))
        return solve(*args, **kwargs)

    simulate_module._solve = counted

    def write() -> None:
        counts = {name: len(found) for name, found in _signatures.items()}
        (Path(folder) / f"{worker}.solve.json").write_text(json.dumps(counts))

    atexit.register(write)


class _Handler(logging.Handler):
    def emit(self, record: logging.LogRecord) -> None:
        found = _RECORD.search(record.getMessage())
        if found and _out:
            kind, program, seconds = found.groups()
            row = [_current[0], _KINDS[kind], program, float(seconds)]
            _out[0].write(json.dumps(row) + "\n")


def pytest_configure(config) -> None:
    folder = os.environ.get(_FOLDER)
    if not folder:
        return
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    _out.append(open(Path(folder) / f"{worker}.jsonl", "a", buffering=1))
    import jax

    jax.config.update("jax_log_compiles", True)
    # one handler, on the parent of JAX's loggers (the records propagate to it)
    logging.getLogger("jax").addHandler(_Handler())
    _count_solve_calls(folder, worker)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_protocol(item, nextitem):
    _current[0] = item.nodeid
    if _out:
        _out[0].write(json.dumps([item.nodeid, "start", "", time.time()]) + "\n")


def pytest_runtest_logfinish(nodeid, location):
    if _out:
        _out[0].write(json.dumps([nodeid, "end", "", time.time()]) + "\n")


# ---- the run and its summary ----


def summarise(folder: Path) -> dict:
    """The records of `folder` added up: per kind, per test file, per program."""
    rows = []
    for path in sorted(folder.glob("*.jsonl")):
        process = path.stem  # (pytest-xdist's controller reports tests it ran not)
        rows += [[process, *json.loads(line)] for line in path.read_text().splitlines()]
    started: dict[tuple[str, str], float] = {}
    wall: collections.Counter = collections.Counter()
    kinds: collections.Counter = collections.Counter()
    files: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    programs: dict[str, list] = collections.defaultdict(lambda: [0, 0.0])
    for process, test, kind, program, value in rows:
        file = test.split("::")[0]
        if kind == "start":
            started[process, test] = value
        elif kind == "end":
            seconds = value - started.pop((process, test), value)
            wall[file] += seconds
            files[file]["wall"] += seconds
        else:
            kinds[kind] += value
            files[file][kind] += value
            if kind == "compilation":
                programs[program][0] += 1
                programs[program][1] += value
    solve_calls: collections.Counter = collections.Counter()
    for path in sorted(folder.glob("*.solve.json")):
        solve_calls.update(json.loads(path.read_text()))
    total = sum(wall.values())
    by_file = sorted(files.items(), key=lambda item: -item[1]["wall"])
    by_program = sorted(programs.items(), key=lambda item: -item[1][1])
    return {
        "test_s": total,
        **{f"{k}_s": kinds[k] for k in _KINDS.values()},
        "compile_share": sum(kinds.values()) / total if total else float("nan"),
        "files": {f: dict(c) for f, c in by_file},
        "programs": {p: {"compiled": n, "s": s} for p, (n, s) in by_program},
        "solve_calls_distinct_by": dict(solve_calls),
    }


def main(argv: list[str]) -> None:
    json_path = None
    if argv[:1] == ["--json"]:
        if len(argv) < 2:
            sys.exit("--json needs a file name")
        json_path, argv = argv[1], argv[2:]
    pytest_args = argv or ["-n", "2", "-q", "-m", "slow"]
    here = Path(__file__).resolve().parent
    with tempfile.TemporaryDirectory() as folder:
        env = dict(os.environ, **{_FOLDER: folder})
        env["PYTHONPATH"] = os.pathsep.join(
            [str(here)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])
        )
        command = [sys.executable, "-m", "pytest", "-p", "suite_compilation"]
        start = time.perf_counter()
        done = subprocess.run([*command, *pytest_args], env=env, cwd=here.parent)
        wall = time.perf_counter() - start
        result = {"pytest": pytest_args, "wall_s": wall, "exit": done.returncode}
        result |= summarise(Path(folder))
    print(
        f"pytest {' '.join(pytest_args)}: {wall:.1f} s wall, tests "
        f"{result['test_s']:.1f} test-seconds, of which tracing "
        f"{result['tracing_s']:.1f} s, lowering {result['lowering_s']:.1f} s, "
        f"XLA compilation {result['compilation_s']:.1f} s "
        f"({100 * result['compile_share']:.0f} %)"
    )
    print(f"\n{'test file':48s} {'wall':>7s} {'trace':>7s} {'lower':>7s} {'XLA':>7s}")
    for file, c in list(result["files"].items())[:20]:
        print(
            f"{file:48s} {c.get('wall', 0):7.1f} {c.get('tracing', 0):7.1f} "
            f"{c.get('lowering', 0):7.1f} {c.get('compilation', 0):7.1f}"
        )
    print(f"\n{'program':40s} {'compiled':>8s} {'XLA s':>7s}")
    for program, p in list(result["programs"].items())[:15]:
        print(f"{program:40s} {p['compiled']:8d} {p['s']:7.1f}")
    print("\ndistinct calls of simulate's program (_solve), the setting left out:")
    for name, n in result["solve_calls_distinct_by"].items():
        print(f"  {name:16s} {n:5d}")
    if json_path:
        Path(json_path).write_text(json.dumps(result, indent=2))
    sys.exit(done.returncode)


if __name__ == "__main__":
    main(sys.argv[1:])
