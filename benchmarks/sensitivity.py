"""Wall time of a Sobol' sensitivity study: design, runs (compilation included),
and the estimation of the indices.

    python benchmarks/sensitivity.py [--base-samples 1024] [--json results.json]
    python benchmarks/run.py --only sensitivity [--quick]

Problem: the default scenario (`beam_lift`: a 2 kg beam lifted by two manipulators
through elastic grasps, 3 s) with 10 uncertain scalars (the x, y, z stiffness of
both grasps, log-normal 20 %; the beam's mass, normal 0.1 kg; the x, y, z
position gains, log-normal 10 %), peak grasp force and deflection kept per
connection (61 output times, the shipped study's solver settings). The Saltelli
design with second-order indices: N (2D + 2) = 22 N runs (22,528 for N = 1024).
Reported: the time to build the study and its design, to run it (`run_study`, one
XLA device per core, compilation included), to estimate first-, total- and
second-order indices with 1,000 bootstrap resamples, and their convergence.
"""

import os

if "XLA_FLAGS" not in os.environ:
    os.environ["XLA_FLAGS"] = (
        f"--xla_force_host_platform_device_count={os.cpu_count() or 1}"
    )

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402

from elasticoop import load_study, montecarlo as mc  # noqa: E402

STUDY = """\
scenario = "beam_lift"

[sampling]
samples = 1
seed = 2024

[time]
samples = 61

[solver]
rtol = 1e-6
atol = 1e-8

[[parameters]]
quantity = "stiffness"
axes = ["x", "y", "z"]
distribution = "lognormal"
relative_spread = 0.2

[[parameters]]
quantity = "mass"
bodies = ["beam"]
distribution = "normal"
absolute_spread = 0.1

[[parameters]]
quantity = "kp"
axes = ["x", "y", "z"]
distribution = "lognormal"
relative_spread = 0.1

[[outputs]]
name = "peak_force"
quantity = "peak_elastic_force"

[[outputs]]
name = "deflection"
quantity = "max_deflection"
"""


def run(quick: bool = False, base_samples: int | None = None) -> dict:
    """The study at `base_samples` base points (default 1024; 16 with `quick`)."""
    if base_samples is None:
        base_samples = 16 if quick else 1024
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "study.toml"
        path.write_text(STUDY)
        start = time.perf_counter()
        nominal = load_study(path).study
        study = mc.sensitivity_study(nominal, "sobol", base_samples, second_order=True)
        design = mc.lhs_strata(study)
        build_s = time.perf_counter() - start
        start = time.perf_counter()
        results = mc.run_study(study, Path(folder) / "store", progress=False)
        run_s = time.perf_counter() - start
    start = time.perf_counter()
    indices = mc.sobol_indices(results, bootstrap=1000)
    estimate_s = time.perf_counter() - start
    start = time.perf_counter()
    mc.sobol_convergence(results, bootstrap=1000)
    convergence_s = time.perf_counter() - start
    top = indices["ST_peak_force"].isel(connection=0)
    order = top.values.argsort()[::-1][:3]
    return {
        "factors": int(indices.sizes["factor"]),
        "base_samples": base_samples,
        "runs": int(study.n_samples),
        "design_shape": list(design.shape),
        "failed": int((results["status"].values != 0).sum()),
        "build_s": build_s,
        "run_s_with_compilation": run_s,
        "estimate_s": estimate_s,
        "convergence_s": convergence_s,
        "total_s": build_s + run_s + estimate_s + convergence_s,
        "top_ST_peak_force_0": {
            str(top["factor"].values[k]): float(top.values[k]) for k in order
        },
        "device": f"{jax.devices()[0].platform} x {len(jax.devices())} "
        f"({platform.processor() or platform.machine()}, {os.cpu_count()} cores)",
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base-samples", type=int, default=1024)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    result = run(base_samples=args.base_samples)
    for key, value in result.items():
        print(f"{key}: {value}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
