"""Parameter identification: a 3-body MobileModel (object + 2 grasps; 6
translational + 6 rotational stiffness and 12 damping parameters) from two 2 s
experiments sampled at 500 Hz, 1 % Gaussian noise on every position and angle
channel, every parameter started 2x too high.

The grasps hold the weight and shake the object with a multisine (1.5-17 Hz) from
small random initial rates. Compared in one run, from the same start and with the
same simulation tolerances (rtol 1e-6, atol 1e-8, far below the noise):

- `identify` with Levenberg-Marquardt and forward-mode sensitivities (the default),
- `identify` with optax L-BFGS and reverse-mode gradients,
- SciPy `least_squares` (trust-region reflective, log-parameters, the same step
  safeguard as `identify`) with 2-point finite-difference Jacobians over a
  NumPy/SciPy simulation of the same model (`reference.solve_ivp_mobile`, RK45),
  capped at `--scipy-nfev` evaluations (each Jacobian costs 25 simulations per
  experiment); its time per Jacobian gives the projected time for as many
  Jacobians as Levenberg-Marquardt needed,
- the equation-error estimate (`equation_error`) on the same noisy data.

Wall times include compilation (each fit runs once in this process). Run
`python benchmarks/identify.py [--quick] [--scipy-nfev N] [--json FILE]`.

`python benchmarks/identify.py --cli [--json FILE]` instead times the two command
lines a user runs on the shipped example (`elasticoop examples`): the documented
fit (`--fit stiffness --axes x y z --init model`) and the fit with no option (the
36 stiffnesses and dampings), each in a fresh process, first with an empty
compilation cache and then with the programs the first run kept, with their
status, loss and iterations.
"""

import argparse
import json
import os
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import elasticoop as eo
from elasticoop._identify import Experiment, identify

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

WHERE = lambda m: (m.stiffness, m.damping)  # noqa: E731
NOISE = 0.01  # of each measured channel's standard deviation
RTOL, ATOL = 1e-6, 1e-8  # simulation tolerances of every fit
UP = (0.0, np.pi / 2, 0.0)


def model_and_state():
    bodies = [
        eo.RigidBody(2.0, (0.02, 0.15, 0.16)),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.25, (1.5e-3, 2.5e-3, 3e-3)),
    ]
    stiffness = [
        (800.0, 900.0, 1000.0, 20.0, 25.0, 30.0),
        (700.0, 850.0, 950.0, 22.0, 18.0, 26.0),
    ]
    damping = [(3.0, 2.5, 2.0, 0.05, 0.04, 0.06), (2.0, 3.5, 2.2, 0.03, 0.05, 0.04)]
    conns = [
        eo.Connection(0, k + 1, stiffness=stiffness[k], damping=damping[k])
        for k in range(2)
    ]
    y0 = jnp.array([[0.0, 0.0, 1.0, *UP], [-0.5, 0.0, 1.0, *UP], [0.5, 0.0, 1.0, *UP]])
    return eo.MobileModel(bodies, conns).with_unloaded_state(y0), y0


def lift(model):
    F = np.zeros((2, 6))
    F[:, 2] = float(jnp.sum(model.bodies.mass)) * model.gravity / 2
    return F


class Multisine(eo.AbstractForce):
    """The grasps hold the weight and shake: $F(t) = F_0 + \\sum_k a_k
    \\sin(2\\pi f_k t + \\varphi_k)$ per coordinate, a persistent excitation."""

    hold: jax.Array  # (2, 6)
    amplitude: jax.Array  # (2, 6, K)
    frequency: jax.Array  # (K,) [Hz]
    phase: jax.Array  # (2, 6, K)

    def __call__(self, t, y, ydot):
        wave = jnp.sin(2 * jnp.pi * self.frequency * t + self.phase)
        return self.hold + jnp.sum(self.amplitude * wave, axis=-1)


def shaking(model, rng):
    frequency = np.array([1.5, 3.0, 5.0, 8.0, 12.0, 17.0])
    scale = np.repeat([1.0, 0.02], 3)[None, :, None]  # N, N m
    amplitude = scale * rng.uniform(0.5, 1.0, size=(2, 6, frequency.size))
    phase = rng.uniform(0.0, 2 * np.pi, size=(2, 6, frequency.size))
    return Multisine(
        jnp.asarray(lift(model)),
        jnp.asarray(amplitude),
        jnp.asarray(frequency),
        jnp.asarray(phase),
    )


def experiments(model, y0, duration, rate=500.0, seed=0):
    """Two experiments: small random initial rates and a multisine shake."""
    ts = jnp.linspace(0.0, duration, int(round(duration * rate)) + 1)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(2):
        rates = rng.normal(size=(3, 6)) * np.repeat([0.05, 0.3], 3)
        force = shaking(model, rng)
        y = np.asarray(eo.simulate(model, y0, rates, ts, forces=force).y)
        sigma = NOISE * np.std(y, axis=0)
        noisy = y + sigma * rng.normal(size=y.shape)
        out.append(Experiment(ts, noisy, y0, rates, forces=force, sigma=sigma))
    return out


def _errors(estimate, truth):
    rel = np.abs(np.asarray(estimate) / truth - 1.0)
    return {
        "max_rel_error_stiffness": float(np.max(rel[:12])),
        "max_rel_error_damping": float(np.max(rel[12:])),
        "rel_errors": rel.tolist(),
    }


def _truth(model):
    return np.concatenate([np.ravel(model.stiffness), np.ravel(model.damping)])


def _two_x_off(model):
    return eqx.tree_at(WHERE, model, (2 * model.stiffness, 2 * model.damping))


def _fit(model, exps, method, max_steps):
    t0 = time.perf_counter()
    result = identify(
        _two_x_off(model),
        exps,
        WHERE,
        method=method,
        init="model",
        max_iterations=max_steps,
        progress=False,
        options=eo.SimulationOptions(rtol=RTOL, atol=ATOL),
    )
    wall = time.perf_counter() - t0
    out = {
        "method": result.method,
        "status": result.status,
        "iterations": result.n_iterations,
        "simulations": result.n_simulations,
        "rejected": result.n_rejected,
        "failed_trials": result.n_failed_trials,
        "wall_s": wall,
        "final_loss": float(result.loss_history[-1]),
        "flagged": [n for n, ok in zip(result.names, result.identifiable) if not ok],
        "max_rel_stderr": float(np.max(result.uncertainty.stderr / result.estimate)),
        **_errors(result.estimate, _truth(model)),
    }
    return out, result


def _numpy_force(force):
    hold, amplitude, frequency, phase = (
        np.asarray(x)
        for x in (force.hold, force.amplitude, force.frequency, force.phase)
    )

    def f(t, y, ydot):
        return hold + np.sum(amplitude * np.sin(2 * np.pi * frequency * t + phase), -1)

    return f


class _TooManyEvaluations(Exception):
    pass


def _scipy_fit(model, exps, max_nfev):
    """SciPy's trust-region least squares on $v = \\log(p / p_{start})$ (so its
    first trust region, radius 1, is a factor e), with the same safeguard as
    `identify`: a simulation needing more than 8x the right-hand-side evaluations
    of the start is stopped and its residuals set to a large constant."""
    import reference
    from scipy.optimize import least_squares

    truth = _truth(model)
    p_start = 2 * truth
    calls = {"n": 0, "rhs": 0, "limit": np.inf}

    def counted(force):
        def f(t, y, ydot):
            calls["rhs"] += 1
            if calls["rhs"] > calls["limit"]:
                raise _TooManyEvaluations
            return force(t, y, ydot)

        return f

    forces = [counted(_numpy_force(e.forces)) for e in exps]

    def residuals(v):
        calls["n"] += 1
        p = p_start * np.exp(v)
        m = eqx.tree_at(
            WHERE,
            model,
            (jnp.asarray(p[:12]).reshape(2, 6), jnp.asarray(p[12:]).reshape(2, 6)),
        )
        out = []
        for e, force in zip(exps, forces):
            calls["rhs"] = 0
            try:
                y = reference.solve_ivp_mobile(
                    m, e.y_init, e.ydot_init, e.ts, force=force, rtol=RTOL, atol=ATOL
                )
                r = (y - np.asarray(e.y)) / np.asarray(e.sigma)
            except _TooManyEvaluations:
                r = np.full(np.shape(e.y), 1e6)
            out.append(r.ravel())
        return np.concatenate(out)

    residuals(np.zeros_like(truth))
    calls["limit"] = 8 * calls["rhs"]
    t0 = time.perf_counter()
    sol = least_squares(
        residuals,
        np.zeros_like(truth),
        jac="2-point",
        method="trf",
        max_nfev=max_nfev,
    )
    wall = time.perf_counter() - t0
    njev = int(sol.njev or 0)
    return {
        "method": f"SciPy least_squares (trf, 2-point FD), max_nfev={max_nfev}",
        "status": sol.message,
        "converged": bool(sol.status > 0),
        "nfev": int(sol.nfev),
        "njev": njev,
        "simulations": calls["n"] * len(exps),
        "wall_s": wall,
        "wall_s_per_jacobian": wall / max(njev, 1),
        "final_loss": float(sol.cost),
        **_errors(p_start * np.exp(sol.x), truth),
    }


def _equation_error(model, exps):
    t0 = time.perf_counter()
    fitted = eo.equation_error(_two_x_off(model), exps, WHERE, window=11)
    wall = time.perf_counter() - t0
    estimate = np.concatenate([np.ravel(fitted.stiffness), np.ravel(fitted.damping)])
    return {
        "method": "equation error (Savitzky-Golay window 11, order 4)",
        "wall_s": wall,
        "negative_estimates": int(np.sum(estimate <= 0)),
        **_errors(estimate, _truth(model)),
    }


def _log(name, r):
    print(
        f"  {name}: {r['wall_s']:.1f} s, {r['simulations']} simulations",
        file=sys.stderr,
        flush=True,
    )


def run(quick: bool, scipy_nfev: int | None = None) -> dict:
    """The benchmark. L-BFGS is capped at 100 iterations (about 0.7 s each on a
    2-core CPU); `quick` uses 0.4 s experiments, 30 L-BFGS iterations and one SciPy
    evaluation."""
    model, y0 = model_and_state()
    duration = 0.4 if quick else 2.0
    exps = experiments(model, y0, duration)
    lm, result = _fit(model, exps, "levenberg-marquardt", max_steps=200)
    _log("Levenberg-Marquardt", lm)
    lbfgs, _ = _fit(model, exps, "lbfgs", max_steps=30 if quick else 100)
    _log("L-BFGS", lbfgs)
    nfev = scipy_nfev or (1 if quick else 3)
    scipy_fit = _scipy_fit(model, exps, max_nfev=nfev)
    _log("SciPy", scipy_fit)
    # Jacobians LM evaluated: one per accepted step and the start's
    projected = scipy_fit["wall_s_per_jacobian"] * (lm["iterations"] + 1)
    return {
        "problem": (
            f"3-body MobileModel, 24 parameters (12 stiffness, 12 damping), 2 "
            f"experiments of {duration} s at 500 Hz ({len(exps[0].ts)} samples x 18 "
            f"channels each), noise {NOISE:.0%} of each channel's std, start 2x off, "
            f"simulation rtol {RTOL}, atol {ATOL}"
        ),
        "device": str(jax.devices()[0]),
        "levenberg_marquardt": lm,
        "lbfgs": lbfgs,
        "scipy": scipy_fit,
        "equation_error": _equation_error(model, exps),
        "scipy_projected_wall_s": projected,
        "scipy_projected_over_lm": projected / lm["wall_s"],
        "report": result.report(),
    }


CLI_FITS = {
    "documented example": ["--fit", "stiffness", "--axes", "x", "y", "z"]
    + ["--init", "model"],
    "no option (36 parameters)": [],
}


def run_cli() -> dict:
    """Time `elasticoop identify` on the shipped example as a user runs it (plots
    included), each fit in a fresh process: first with an empty compilation
    cache (`ELASTICOOP_CACHE_DIR` a new folder: a first run, compiling), then
    again with the programs that run kept (a later run)."""
    import pathlib
    import subprocess
    import tempfile

    from elasticoop._examples import example_files

    files = example_files()
    scenario = pathlib.Path(str(files["plate_lift"]))
    data = scenario.with_name("plate_lift_measured.csv")
    out = {"device": str(jax.devices()[0]), "cpus": os.cpu_count()}
    for name, options in CLI_FITS.items():
        with tempfile.TemporaryDirectory() as tmp:
            env = dict(os.environ, ELASTICOOP_CACHE_DIR=str(pathlib.Path(tmp) / "c"))
            for run in ("first run", "later run"):
                folder = pathlib.Path(tmp) / run.replace(" ", "_")
                argv = [sys.executable, "-m", "elasticoop", "identify"]
                argv += [str(scenario), str(data), *options, "-o", str(folder), "-q"]
                t0 = time.perf_counter()
                done = subprocess.run(argv, capture_output=True, text=True, env=env)
                wall = time.perf_counter() - t0
                if done.returncode != 0:
                    raise RuntimeError(f"{' '.join(argv)} failed:\n{done.stderr}")
                report = json.loads((folder / "report.json").read_text())
                out[f"{name}, {run}"] = {
                    "command": "elasticoop identify plate_lift.toml "
                    "plate_lift_measured.csv " + " ".join(options),
                    "wall_s": wall,
                    "fit_s": report["wall_time_s"],
                    "status": report["status"],
                    "iterations": report["iterations"],
                    "loss": report["loss_history"][-1],
                }
                print(f"  {name}, {run}: {wall:.1f} s", file=sys.stderr, flush=True)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="smoke-test sizes")
    parser.add_argument(
        "--cli", action="store_true", help="time the shipped example's command lines"
    )
    parser.add_argument(
        "--scipy-nfev", type=int, help="SciPy's max_nfev (default 3; 1 with --quick)"
    )
    parser.add_argument("--json")
    args = parser.parse_args()
    if args.cli:
        out = run_cli()
        print(json.dumps(out, indent=1))
        if args.json:
            with open(args.json, "w") as f:
                json.dump(out, f, indent=1)
        return
    out = run(args.quick, args.scipy_nfev)
    print(out["problem"], "on", out["device"])
    print(
        f"{'method':<58} {'iters':>5} {'sims':>6} {'wall s':>7} "
        f"{'max err k':>9} {'max err d':>9}  status"
    )
    for key in ("levenberg_marquardt", "lbfgs", "scipy", "equation_error"):
        r = out[key]
        iters = r.get("iterations", r.get("njev", ""))
        print(
            f"{r['method']:<58} {iters:>5} {r.get('simulations', ''):>6} "
            f"{r['wall_s']:>7.1f} {r['max_rel_error_stiffness']:>9.2%} "
            f"{r['max_rel_error_damping']:>9.2%}  {r.get('status', '')}"
        )
    projected, ratio = out["scipy_projected_wall_s"], out["scipy_projected_over_lm"]
    print(
        f"SciPy: {out['scipy']['wall_s_per_jacobian']:.1f} s per Jacobian; for as "
        f"many Jacobians as Levenberg-Marquardt used: {projected:.0f} s projected, "
        f"{ratio:.0f}x its wall time"
    )
    print(out["report"])
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)


if __name__ == "__main__":
    main()
