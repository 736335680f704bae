"""Where the vector-Jacobian product of `simulate`'s vector field spends its time.

    python benchmarks/product_parts.py [--quick] [--json out.json]
    taskset -c 0 python benchmarks/product_parts.py     # on one core

The reverse-mode gradient of `simulate` spends most of its time in the products of
its vector field, one per stage of each step (`benchmarks/defaults.py`). Here the
field is rebuilt from the library's own pieces in three parts: the restoring forces
(the model's `restoring_forces`, elastic and damping), the inertial part (the mass
blocks, the velocity terms and the block solve, as `accelerations` assembles them)
and the applied force. The rebuilt field is checked first against the library's
(its value and its product, to a relative 1e-13, `check`; an error otherwise), so
that the parts timed are the library's. Then each part in turn is left out:
replaced by a stand-in that costs next to nothing but keeps the dependences (the
restoring forces by `1e-3 (Y + Y')` times the sum of two parameters, the inertial
part by the right-hand side over the bodies' masses, the applied force by zeros
plus `1e-3 t`).

Each variant (`library`, `rebuilt`, `without_<part>`) is timed as the field alone
and as its product in the state and the 24 stiffness and damping parameters, each
`n_evals` times in a compiled loop on single states (`field_us`, `product_us`: per
call), at the middle output of a run of `default_scenario()` (3 bodies, 2
connections), nudged by the previous result, as `defaults.py` times the library's:
`single` for the scenario's parameters, `vmap` under `vmap` over 8 parameter sets
(all 8 per call). The loops are timed in turn, best of `rounds` rounds.
`field_ops` and `product_ops`: the operations of each compiled loop that XLA's CPU
runtime runs one after the other (the fusions and other instructions of the entry
computation and of the loop's body, less those that move no data).

`linearization`: the library's product taken apart into its primal half (the
field evaluated again with what the transpose needs, `jax.vjp`'s residuals:
`residual_floats_per_set`) and its transpose, timed alone in a loop of its own
(`transpose_us`: `jax.vjp` taken once before the loop, each pullback nudged by
the previous result), for one set and under `vmap`: what a product would cost if
its primal half came at no cost.

Reading the results: a part's cost (`cost_in_field_us`, `cost_in_product_us`) is
the library's time less the time without it; its cost in the product over its cost
in the field, against the library's `product_over_field`, says whether the part
makes the product dearer than the field or cheaper. The costs of the three parts
need not add up to the whole (leaving a part out also changes what XLA fuses
around it), and the `rebuilt` row shows how far the rebuilt field's own times stand
from the library's.

`structured_inertial`: the rebuilt field with the inertial part's angular rows as
a `jax.custom_jvp` whose tangent rule is written in the structure of Euler's
equations instead of differentiating the library's expressions (the cofactors of
$L_\\omega$, the velocity terms). With $\\tau = L_\\omega^{-T} r$ the body-frame
moment of the right-hand side $r$,
$\\alpha = I^{-1}(\\tau - \\omega\\times I\\omega)$ and
$\\ddot{\\mathcal{A}} = L_\\omega^{-1}(\\alpha - \\dot L_\\omega\\dot{\\mathcal{A}})$,
the tangent is
$L_\\omega^{-1}(d\\alpha - d(\\dot L_\\omega\\dot{\\mathcal{A}})
- dL_\\omega\\,\\ddot{\\mathcal{A}})$: one more solve with the factors the
value already has. It is checked against the library as the rebuilt field is
(`check_structured_inertial`, at a state where the bodies turn) and timed as the
variants are: what a product written by hand for the largest part would gain.

At smoke size (`--quick`): 100 evaluations per loop, one round.
"""

import functools
import re
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _timing import interleaved_best_times  # noqa: E402
from defaults import parameter_sets  # noqa: E402
from gradients import (  # noqa: E402
    evaluation_loop,
    field_of_parameters,
    max_rel_diff,
    parameters,
    product_loop,
    with_parameters,
)

import elasticoop as eo  # noqa: E402
from elasticoop import _lagrange, _simulate  # noqa: E402
from elasticoop._forces import check_force  # noqa: E402
from elasticoop._mass_blocks import (  # noqa: E402
    FactoredMassBlocks,
    _cofactors,
    _sum,
    _times,
)

PARTS = ("restoring", "inertial", "applied")
WIDTH = 8  # parameter sets under `vmap`


def inertial_accelerations(model, y, ydot, rhs):
    """Y'' from the right-hand side `rhs` = G + F - elastic - damping `(bodies, 6)`:
    the mass blocks, the velocity terms and the block solve of `_lagrange`."""
    q, v = _lagrange._coordinates(y), _lagrange._coordinates(ydot)
    inertia = model.bodies.inertia
    blocks = FactoredMassBlocks(
        model.bodies.mass,
        (inertia[:, 0], inertia[:, 1], inertia[:, 2]),
        model.rotation.angular_velocity_rows(q[3:6]),
    )
    c = _lagrange._structured_velocity_terms(model, blocks, q, v)
    b = tuple(r - c_k for r, c_k in zip(_lagrange._coordinates(rhs), c, strict=True))
    return jnp.stack(blocks.solve(b), -1)


def _by_rows(L, x):
    """$L x$ for the rows `L` of a 3x3 matrix (entries arrays or structural floats)."""
    return tuple(_sum(*(_times(L[r][c], x[c]) for c in range(3))) for r in range(3))


def _by_columns(L, x):
    """$L^T x$."""
    return tuple(_sum(*(_times(L[r][c], x[r]) for r in range(3))) for c in range(3))


def _cross(a, b):
    return tuple(a[(k + 1) % 3] * b[(k + 2) % 3] - a[(k + 2) % 3] * b[(k + 1) % 3]
                 for k in range(3))  # fmt: skip


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def angle_accelerations(rotation, angles, rates, r, inertia):
    """$\\ddot{\\mathcal{A}}$ of every body from its angles, angle rates, the
    angular rows $r$ of the right-hand side $G + F - \\partial\\Pi/\\partial Y -
    \\partial R/\\partial\\dot Y$ and the principal moments (three arrays
    `(bodies,)` each), in the structure of Euler's equations."""
    return _angle_accelerations(rotation, angles, rates, r, inertia)[0]


def _angle_accelerations(rotation, angles, rates, r, inertia):
    L = rotation.angular_velocity_rows(angles)
    C = _cofactors(L)
    inverse_det = 1.0 / _sum(*(_times(L[0][c], C[0][c]) for c in range(3)))

    def solve_transposed(b):  # L^-T b
        return tuple(x * inverse_det for x in _by_rows(C, b))

    def solve(e):  # L^-1 e
        return tuple(x * inverse_det for x in _by_columns(C, e))

    omega, omega_rate = jax.jvp(
        lambda a: rotation.angular_velocity_components(a, rates), (angles,), (rates,)
    )
    spin = tuple(i * w for i, w in zip(inertia, omega, strict=True))
    tau = solve_transposed(r)
    alpha = tuple(
        (t - g) / i for t, g, i in zip(tau, _cross(omega, spin), inertia, strict=True)
    )
    acc = solve(tuple(a - w for a, w in zip(alpha, omega_rate, strict=True)))
    return acc, (L, solve_transposed, solve, omega, spin, tau, alpha)


@angle_accelerations.defjvp
def _angle_accelerations_jvp(rotation, primals, tangents):
    angles, rates, r, inertia = primals
    d_angles, d_rates, d_r, d_inertia = tangents
    acc, (L, solve_transposed, solve, omega, spin, tau, alpha) = _angle_accelerations(
        rotation, *primals
    )

    def d_rows(x):  # dL x
        return jax.jvp(
            lambda a: rotation.angular_velocity_components(a, x), (angles,), (d_angles,)
        )[1]

    def d_columns(x):  # dL^T x
        return jax.jvp(
            lambda a: _by_columns(rotation.angular_velocity_rows(a), x),
            (angles,),
            (d_angles,),
        )[1]

    def omega_rate_of(a, v):  # (dL/dt) v at angles a, rates v
        return jax.jvp(
            lambda b: rotation.angular_velocity_components(b, v), (a,), (v,)
        )[1]

    d_omega = tuple(
        x + y
        for x, y in zip(
            d_rows(rates), rotation.angular_velocity_components(angles, d_rates)
        )
    )
    d_omega_rate = jax.jvp(omega_rate_of, (angles, rates), (d_angles, d_rates))[1]
    d_tau = solve_transposed(tuple(x - y for x, y in zip(d_r, d_columns(tau))))
    d_spin = tuple(
        di * w + i * dw for di, w, i, dw in zip(d_inertia, omega, inertia, d_omega)
    )
    d_gyro = tuple(x + y for x, y in zip(_cross(d_omega, spin), _cross(omega, d_spin)))
    d_alpha = tuple(
        (dt - dg - di * a) / i
        for dt, dg, di, a, i in zip(d_tau, d_gyro, d_inertia, alpha, inertia)
    )
    d_acc = solve(
        tuple(a - w - x for a, w, x in zip(d_alpha, d_omega_rate, d_rows(acc)))
    )
    return acc, d_acc


def structured_inertial_accelerations(model, y, ydot, rhs):
    """`inertial_accelerations` with the angular rows by `angle_accelerations`."""
    q, v = _lagrange._coordinates(y), _lagrange._coordinates(ydot)
    b = _lagrange._coordinates(rhs)
    inertia = model.bodies.inertia
    moments = (inertia[:, 0], inertia[:, 1], inertia[:, 2])
    angular = angle_accelerations(model.rotation, q[3:6], v[3:6], b[3:6], moments)
    linear = [x / model.bodies.mass for x in b[0:3]]
    return jnp.stack(linear + list(angular), -1)


def rebuilt(scenario, restoring=True, inertial=True, applied=True):
    """`field_of_parameters(scenario)` rebuilt from the library's pieces, each of
    the three parts the library's (true) or a stand-in (false); `inertial=
    "structured"`: the inertial part by `structured_inertial_accelerations`."""
    s = scenario
    force = check_force(s.forces, s.y_init, s.ydot_init, s.ts)
    accelerations = (
        structured_inertial_accelerations
        if inertial == "structured"
        else inertial_accelerations
    )

    def field(t, x, params):
        model = with_parameters(s.model, params)
        y, ydot, _, _ = _simulate._unpack(x)
        if applied:
            f = _simulate._applied(model, force, t, y, ydot)
        else:
            f = jnp.zeros_like(y) + 1e-3 * t
        if restoring:
            elastic, damping = model.restoring_forces(y, ydot)
        else:
            elastic = damping = 1e-3 * (y + ydot) * (params[0][0, 0] + params[1][0, 0])
        rhs = model.gravity_forces() + f - elastic - damping
        if inertial:
            yddot = accelerations(model, y, ydot, rhs)
        else:
            yddot = rhs / model.bodies.mass[:, None]
        return _simulate._pack(ydot, yddot, jnp.sum(f * ydot), jnp.sum(damping * ydot))

    return field


def turned(x):
    """The packed state `x` with every body's angles and angle rates moved off the
    scenario's (whose bodies do not turn), so that a check exercises the angular
    terms."""
    y, ydot, work, dissipated = _simulate._unpack(x)
    offset = jnp.array([0.1, -0.2, 0.3])
    y = y.at[:, 3:].add(offset)
    ydot = ydot.at[:, 3:].add(2.0 * offset[::-1])
    return _simulate._pack(y, ydot, work, dissipated)


def check_rebuilt(library, field, t0, x0, x_bar0, params) -> dict:
    """The rebuilt field's value and product against the library's: the largest
    relative differences; an error above 1e-13."""

    def value_and_product(f):
        value, pullback = jax.vjp(lambda x, p: f(t0, x, p), x0, params)
        return value, jax.tree.leaves(pullback(x_bar0))

    a, da = jax.jit(lambda: value_and_product(library))()
    b, db = jax.jit(lambda: value_and_product(field))()
    diffs = {
        "field_max_rel_diff": max_rel_diff(b, a),
        "product_max_rel_diff": max(map(max_rel_diff, db, da)),
    }
    if max(diffs.values()) > 1e-13:
        raise RuntimeError(f"the rebuilt field is not the library's: {diffs}")
    return diffs


_CALLS = re.compile(
    r"\b(body|condition|branch_computations|true_computation|false_computation"
    r"|to_apply)=(\{[^}]*\}|%?[\w.\-]+)"
)
_COMPUTATION = re.compile(r"^(ENTRY )?%(\S+) .*\{\s*$")
_INSTRUCTION = re.compile(r"^\s+(?:ROOT )?%\S+ = .+? ([a-z][\w\-]*)\((.*)$")
_FREE = {"parameter", "constant", "get-tuple-element", "tuple", "bitcast", "after-all"}


def operations(compiled) -> int:
    """The operations XLA's CPU runtime runs one by one in a compiled function:
    the instructions of the entry computation and of the computations it reaches
    through loops, conditionals and calls (a fusion is one), less those that
    move no data (parameters, constants, tuples, bitcasts)."""
    computations, entry, current = {}, None, None
    for line in compiled.as_text().splitlines():
        if head := _COMPUTATION.match(line):
            current = head.group(2)
            computations[current] = []
            entry = current if head.group(1) else entry
        elif line.startswith("}"):
            current = None
        elif current and (instruction := _INSTRUCTION.match(line)):
            computations[current].append(instruction.groups())
    count, todo, seen = 0, [entry], set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        for op, rest in computations[name]:
            count += op not in _FREE
            if op == "fusion":
                continue
            for key, called in _CALLS.findall(rest):
                if key != "to_apply" or op == "call":
                    todo += [c.strip(" %") for c in called.strip("{}").split(",")]
    return count


def transpose_loop(field, t0, x0, x_bar0, params, n_evals: int, width: int | None):
    """A compiled loop of `n_evals` transposes of the field's linearization at
    `(t0, x0)`: `jax.vjp` taken once before the loop (its residuals held), each
    pullback nudged by the previous result, as `product_loop` nudges the point.
    What the product would cost if its primal half came at no cost. With `width`:
    under `vmap` over that many parameter sets (leading axis)."""

    def linearize(p):
        return jax.vjp(lambda x, q: field(t0, x, q), x0, p)[1]

    def transpose(pullback, x_bar):
        x_bar, p_bar = pullback(x_bar0 + 1e-12 * x_bar)
        return x_bar, jnp.sum(p_bar[0]) + jnp.sum(p_bar[1])

    batch = () if width is None else (width,)
    if width is not None:
        linearize, transpose = jax.vmap(linearize), jax.vmap(transpose)

    @jax.jit
    def run(p):
        pullback = linearize(p)

        def body(k, carry):
            x_bar, acc = carry
            x_bar, a = transpose(pullback, x_bar)
            return x_bar, acc + a

        start = (jnp.zeros((*batch, *x0.shape)), jnp.zeros(batch))
        return jax.lax.fori_loop(0, n_evals, body, start)

    return run


def residual_floats(field, t0, x0, params) -> int:
    """The floating-point numbers the field's linearization keeps for its
    transpose (the residuals of `jax.vjp`), one parameter set."""
    pullback = jax.eval_shape(
        lambda p: jax.vjp(lambda x, q: field(t0, x, q), x0, p)[1], params
    )
    return sum(
        int(np.prod(leaf.shape))
        for leaf in jax.tree.leaves(pullback)
        if jnp.issubdtype(leaf.dtype, jnp.floating)
    )


def run(quick: bool = False) -> dict:
    n_evals, rounds = (100, 1) if quick else (5000, 15)
    s = eo.default_scenario()
    traj = eo.simulate(s.model, s.y_init, s.ydot_init, s.ts, forces=s.forces)
    states = jax.vmap(_simulate._pack)(traj.y, traj.ydot, traj.work, traj.dissipated)
    middle = states.shape[0] // 2
    t0, x0, x_bar0 = traj.ts[middle], states[middle], states[middle + 1]
    params = parameters(s.model)
    sets = parameter_sets(params, WIDTH)

    library = field_of_parameters(s)
    fields = {"library": library, "rebuilt": rebuilt(s)}
    fields |= {f"without_{p}": rebuilt(s, **{p: False}) for p in PARTS}
    fields["structured_inertial"] = rebuilt(s, inertial="structured")
    check = check_rebuilt(library, fields["rebuilt"], t0, x0, x_bar0, params)
    # (the scenario's bodies do not turn: checked where they do, with a cotangent
    # in the angular rows)
    check_structured = check_rebuilt(
        library, fields["structured_inertial"], t0, turned(x0), turned(x_bar0), params
    )

    calls, ops = {}, {}
    for tag, width, args in (("single", None, params), ("vmap", WIDTH, sets)):
        for name, field in fields.items():

            def evaluate(params, carry, field=field):
                x_bar, acc = carry
                return field(t0 + 1e-12 * acc, x0 + 1e-12 * x_bar, params), acc

            loops = {
                "field": evaluation_loop(evaluate, x0, n_evals, width),
                "product": product_loop(field, t0, x0, x_bar0, n_evals, width),
            }
            if name == "library":
                loops["transpose"] = transpose_loop(
                    field, t0, x0, x_bar0, params, n_evals, width
                )
            for kind, loop in loops.items():
                calls[tag, name, kind] = (loop, (args,))
                ops[tag, name, kind] = operations(loop.lower(args).compile())
    times = interleaved_best_times(calls, rounds)
    us = {key: 1e6 * t / n_evals for key, t in times.items()}

    def rows(tag):
        out = []
        for name in fields:
            field_us, product_us = us[tag, name, "field"], us[tag, name, "product"]
            row = {
                "variant": name,
                "field_us": field_us,
                "product_us": product_us,
                "product_over_field": product_us / field_us,
                "field_ops": ops[tag, name, "field"],
                "product_ops": ops[tag, name, "product"],
            }
            if name.startswith("without_"):
                row["cost_in_field_us"] = us[tag, "library", "field"] - field_us
                row["cost_in_product_us"] = us[tag, "library", "product"] - product_us
            out.append(row)
        return out

    def split(tag):
        product_us = us[tag, "library", "product"]
        transpose_us = us[tag, "library", "transpose"]
        return {
            "product_us": product_us,
            "transpose_us": transpose_us,
            "transpose_share": transpose_us / product_us,
            "transpose_ops": ops[tag, "library", "transpose"],
        }

    return {
        "problem": f"default_scenario() (3 bodies, 2 connections), state at output "
        f"{middle} of {states.shape[0]} (t = {float(t0):g} s), 24 parameters "
        f"(stiffness, damping); single set and vmap over {WIDTH} sets; "
        f"{n_evals} evaluations per loop, best of {rounds} rounds",
        "check": check,
        "check_structured_inertial": check_structured,
        "single": {"sets": 1, "rows": rows("single")},
        "vmap": {"sets": WIDTH, "rows": rows("vmap")},
        "linearization": {
            "residual_floats_per_set": residual_floats(library, t0, x0, params),
            "single": split("single"),
            "vmap": split("vmap"),
        },
    }


if __name__ == "__main__":
    from _cli import main

    main(run, __doc__)
