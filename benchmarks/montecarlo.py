"""Monte Carlo throughput of `run_study` against a loop of SciPy `solve_ivp` runs.

    python benchmarks/montecarlo.py [--quick] [--json results.json]

Problem: the 3-body MobileModel (object + 2 grasps, 2 connections), 2 s simulated,
Tsit5 at rtol 1e-8, atol 1e-10 (SciPy's tolerances), and Dopri8 at rtol 1e-9, atol
1e-11 (at batch 256, 1024 and 4096; its error at rtol 1e-8 is about 2.6x SciPy's, at
1e-9 below it: `max_error_nominal`), grasp stiffness log-normal (12 scalars, 20 %
scatter), constant lift; kept per sample: peak elastic force per connection and
final object pose error (21 output times). For each batch size B the study has B
samples, one chunk, integrated `run_study`'s default width (`default_batch_width`:
128 on a CPU, up to 131072 on a GPU, or `B / devices` when fewer) at a time on
each device (`vmap`; each waiting sample starts as one stops; the host's cores are
exposed as devices, so both cores of a 2-core machine work).

Reported per B: trajectories per wall-second and simulated seconds per wall-second
(after compilation, best of `repeats`), the compile time, and memory per sample
(XLA's memory analysis of the compiled chunk: arguments + outputs + temporaries,
divided by B; and the `chunk_size_for` estimate). Side by side, the same samples
integrated one by one by `scipy.integrate.solve_ivp` (DOP853, about 2.3x faster
than RK45 on this problem; same tolerances) over
the NumPy right-hand side of `benchmarks/reference.py`; the loop is timed on a
subset of samples and its time per trajectory extrapolated to B. Accuracy
(`max_error_nominal`): max |Y - Y_ref| over the outputs for the nominal stiffness,
Y_ref by Dopri8 at rtol 1e-13, of SciPy's run and of each configuration.
"""

import os
import sys

if "XLA_FLAGS" not in os.environ:
    # one XLA device per core, so that a study shards over all of them
    os.environ["XLA_FLAGS"] = (
        f"--xla_force_host_platform_device_count={os.cpu_count() or 1}"
    )

import argparse  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh  # noqa: E402

import elasticoop as eo  # noqa: E402
from elasticoop import montecarlo as mc  # noqa: E402
from elasticoop.montecarlo.execution import (  # noqa: E402
    _global_array,
    _replicated,
    _run_batch,
    working_memory_per_sample,
)

sys.path.insert(0, str(Path(__file__).resolve().parent))
import reference  # noqa: E402

UP = (0.0, np.pi / 2, 0.0)
T_END = 2.0


def three_body_study(
    n_samples: int, solver: str = "tsit5", rtol: float = 1e-8
) -> mc.Study:
    """The study: `n_samples` stiffness draws, `solver` at `rtol` (atol rtol/100)."""
    bodies = [
        eo.RigidBody(2.0, (0.02, 0.15, 0.16)),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.25, (1.5e-3, 2.5e-3, 3e-3)),
    ]
    damp = (3.0, 2.5, 2.0, 0.05, 0.04, 0.06)
    conns = [
        eo.Connection(0, i, stiffness=(800, 900, 1000, 20, 25, 30), damping=damp)
        for i in (1, 2)
    ]
    y0 = np.array([[0, 0, 1, *UP], [-0.5, 0, 1, *UP], [0.5, 0, 1, *UP]])
    model = eo.MobileModel(bodies, conns).with_unloaded_state(y0)
    lift = np.zeros((2, 6))
    lift[:, 2] = 12.0
    return mc.Study(
        model,
        y0,
        np.zeros_like(y0),
        np.linspace(0.0, T_END, 21),
        forces=lift,
        parameters=[
            mc.Parameter(
                "stiffness",
                lambda m: m.stiffness,
                mc.LogNormal(0.0, 0.2),
                relative=True,
            )
        ],
        outputs={"peak_force": mc.peak_elastic_force(), "error": mc.final_pose_error()},
        n_samples=n_samples,
        key=0,
        options=eo.SimulationOptions(solver=solver, rtol=rtol, atol=rtol / 100),
    )


_MEMORY_PER_SAMPLE: dict = {}


def _memory_per_sample(study, batch_width, devices, config):
    """XLA's memory analysis of the compiled chunk (the whole study), per
    sample; compiled once per configuration (`config`: solver, tolerance),
    number of samples, width and devices."""
    key = (config, study.n_samples, batch_width, len(devices))
    if key not in _MEMORY_PER_SAMPLE:
        _MEMORY_PER_SAMPLE[key] = _analysed_memory_per_sample(
            study, batch_width, devices
        )
    return _MEMORY_PER_SAMPLE[key]


def _analysed_memory_per_sample(study, batch_width, devices):
    mesh = Mesh(np.array(devices), ("samples",))
    shape = (len(devices), -(-study.n_samples // len(devices)))
    index = _global_array(mesh, np.zeros(shape, np.int64))
    strata = _global_array(mesh, np.zeros((*shape, 0), np.int32))
    started = _global_array(mesh, np.ones(shape, bool))
    at_rest = study.initial == "equilibrium"
    starts = _global_array(
        mesh, np.zeros((*shape, *(study.y_init.shape if at_rest else (0,))))
    )
    # the chunk exactly as `run_study` compiles it (the study replicated on the mesh)
    lowered = _run_batch.lower(
        _replicated(mesh, study), mesh, index, strata, started, starts, batch_width
    )
    stats = lowered.compile().compiled.memory_analysis()
    if stats is None:
        return None
    total = (
        stats.argument_size_in_bytes
        + stats.output_size_in_bytes
        + stats.temp_size_in_bytes
    )
    return total / (shape[0] * shape[1])


def jax_throughput(
    batch: int,
    repeats: int,
    solver: str = "tsit5",
    rtol: float = 1e-8,
    batch_width: int | None = None,
) -> dict:
    devices = jax.devices()
    n_dev = min(len(devices), batch)
    devices = devices[:n_dev]
    study = three_body_study(batch, solver, rtol)
    # run_study's default width unless given (`default_batch_width`)
    width = batch_width or mc.default_batch_width(
        study, mc.memory_budget_for(devices), n_dev, platform=devices[0].platform
    )
    run = lambda: mc.run_study(  # noqa: E731
        study, chunk_size=batch, batch_width=width, devices=devices, progress=False
    )
    t0 = time.perf_counter()
    ds = run()
    first = time.perf_counter() - t0
    times = []
    # a long run is its own average: one repeat above 1000 samples
    for _ in range(repeats if batch < 1000 else 1):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    best = min(times)
    summary = mc.summary(ds)
    lanes = width * n_dev
    return {
        "solver": solver,
        "rtol": rtol,
        "batch": batch,
        "devices": n_dev,
        "batch_width": width,
        "compile_and_first_run_s": first,
        "run_s": best,
        "trajectories_per_s": batch / best,
        "simulated_s_per_wall_s": batch * T_END / best,
        "failed": summary["n_failed"],
        "memory_per_sample_bytes_xla": _memory_per_sample(
            study, width, devices, (solver, rtol)
        ),
        "memory_per_sample_bytes_estimate": working_memory_per_sample(study),
        "lanes": lanes,
    }


def scipy_per_trajectory(n: int) -> dict:
    study = three_body_study(max(n, 1))
    values = mc.sample_parameters(study, np.arange(n))
    inputs = study.inputs
    force = np.asarray(inputs.forces.F)
    times = []
    for s in range(n):
        model = eqx.tree_at(lambda m: m.stiffness, inputs.model, values["stiffness"][s])
        t0 = time.perf_counter()
        reference.solve_ivp_mobile(
            model,
            np.asarray(inputs.y_init),
            np.asarray(inputs.ydot_init),
            study.ts,
            force=force,
            rtol=1e-8,
            atol=1e-10,
            method="DOP853",
        )
        times.append(time.perf_counter() - t0)
    return {"samples_timed": n, "s_per_trajectory": float(np.mean(times))}


def accuracy() -> dict:
    """Max |Y - Y_ref| over the outputs of the study's nominal model (its
    unscaled stiffness), Y_ref by Dopri8 at rtol 1e-13: SciPy's DOP853 at rtol
    1e-8 and each of the library's configurations in `CONFIGS`."""
    study = three_body_study(1)
    inputs, ts = study.inputs, jnp.asarray(study.ts)
    args = (inputs.model, inputs.y_init, inputs.ydot_init, ts)

    def error(y):
        return float(np.max(np.abs(np.asarray(y) - np.asarray(ref))))

    def simulate(solver, rtol, atol):
        options = eo.SimulationOptions(solver=solver, rtol=rtol, atol=atol)
        return eo.simulate(*args, forces=inputs.forces, **options.kwargs()).y

    ref = simulate("dopri8", 1e-13, 1e-15)
    scipy_y = reference.solve_ivp_mobile(
        inputs.model,
        np.asarray(inputs.y_init),
        np.asarray(inputs.ydot_init),
        np.asarray(ts),
        force=np.asarray(inputs.forces.F),
        rtol=1e-8,
        atol=1e-10,
        method="DOP853",
    )
    out = {"scipy_dop853_rtol_1e-08": error(scipy_y)}
    for solver, rtol in CONFIGS:
        out[f"{solver}_rtol_{rtol:.0e}"] = error(simulate(solver, rtol, rtol / 100))
    return out


# The library's configurations timed: Tsit5 (the default solver) at SciPy's
# tolerance, and Dopri8 at a tolerance where its error is at most SciPy's
# (`accuracy`: on this problem Dopri8 at rtol 1e-8 is about 2.6x less accurate
# than SciPy's DOP853 at rtol 1e-8, at 1e-9 more accurate).
CONFIGS = (("tsit5", 1e-8), ("dopri8", 1e-9))


def run(
    quick: bool,
    batches: tuple[int, ...] | None = None,
    batch_widths: tuple[int | None, ...] = (None,),
) -> dict:
    """Every configuration of `CONFIGS` at each of `batches` (default: the
    standard sizes below) and each of `batch_widths` (None: `run_study`'s
    default)."""
    repeats = 1 if quick else 2
    scipy = scipy_per_trajectory(2 if quick else 6)
    if batches is None:
        standard = (1, 16, 64) if quick else (1, 16, 256, 1024, 4096)
        runs = [(b, *CONFIGS[0]) for b in standard]
        runs += [(b, *CONFIGS[1]) for b in ((16,) if quick else (256, 1024, 4096))]
    else:
        runs = [(b, *config) for config in CONFIGS for b in batches]
    rows = []
    for (batch, solver, rtol), width in itertools.product(runs, batch_widths):
        if width is not None and width * len(jax.devices()) > batch:
            continue  # wider than the batch: the same as a smaller width
        row = jax_throughput(batch, repeats, solver, rtol, width)
        loop_s = scipy["s_per_trajectory"] * batch
        row["scipy_loop_s_extrapolated"] = loop_s
        row["speedup_vs_scipy_loop"] = loop_s / row["run_s"]
        rows.append(row)
    return {
        "problem": (
            "3-body MobileModel (2 connections), 2 s simulated, Tsit5 at rtol "
            "1e-8 and Dopri8 at rtol 1e-9 (atol rtol/100), SciPy DOP853 at rtol "
            "1e-8; 12 log-normal stiffness scalars; reductions kept"
        ),
        "max_error_nominal": accuracy(),
        "device": f"{jax.devices()[0].platform} ({jax.devices()[0].device_kind}) "
        f"x {len(jax.devices())} "
        f"({platform.processor() or platform.machine()}, {os.cpu_count()} cores)",
        "scipy": scipy,
        "rows": rows,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--json", type=Path)
    parser.add_argument(
        "--batches", type=int, nargs="+", help="batch sizes (default: the standard)"
    )
    parser.add_argument(
        "--batch-widths",
        type=int,
        nargs="+",
        help="samples per device at once (default: run_study's default)",
    )
    args = parser.parse_args()
    widths = tuple(args.batch_widths) if args.batch_widths else (None,)
    result = run(args.quick, tuple(args.batches) if args.batches else None, widths)
    print(result["problem"])
    print("device:", result["device"])
    print(
        f"SciPy solve_ivp (DOP853) loop: "
        f"{result['scipy']['s_per_trajectory'] * 1e3:.1f} ms "
        f"per trajectory (mean of {result['scipy']['samples_timed']}), "
        f"extrapolated linearly to each batch"
    )
    print("max error, nominal model:", result["max_error_nominal"])
    header = (
        f"{'solver':>7} {'rtol':>6} {'batch':>6} {'dev':>4} {'width':>6} "
        f"{'compile s':>10} "
        f"{'run s':>8} {'traj/s':>9} "
        f"{'sim-s/s':>9} {'loop s':>9} {'speedup':>8} {'MB/sample':>10}"
    )
    print(header)
    for r in result["rows"]:
        mem = r["memory_per_sample_bytes_xla"]
        print(
            f"{r['solver']:>7} {r['rtol']:>6.0e} {r['batch']:>6} {r['devices']:>4} "
            f"{r['batch_width']:>6} "
            f"{r['compile_and_first_run_s']:>10.2f} "
            f"{r['run_s']:>8.3f} {r['trajectories_per_s']:>9.1f} "
            f"{r['simulated_s_per_wall_s']:>9.1f} "
            f"{r['scipy_loop_s_extrapolated']:>9.2f} "
            f"{r['speedup_vs_scipy_loop']:>8.1f} "
            f"{(mem or float('nan')) / 1e6:>10.3f}"
        )
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
