"""The longest step `simulate` takes: the solvers' stability radii against their
closed forms, the bound of the linearized rates against the eigenvalues, and the
derivatives of a run that starts at rest in an equilibrium against central
differences (before the bound, `jax.grad` gave 1e11 where they give 0.77)."""

import sys
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import three_body_model, three_body_state

import elasticoop as eo
from elasticoop._integrate.stability import stability_radius
from elasticoop._lagrange import linear_rate_bound

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from step_bound import beam_at_rest, exact_rate  # noqa: E402  (the benchmark's)

# the stability radius is found on a grid of radii this fine
GRID = 0.005


def test_stability_radius_of_the_low_orders_is_their_closed_form():
    # Bosh3: R = 1 + z + z^2/2 + z^3/6, |R(iy)|^2 = 1 - y^4/12 + y^6/36: stable on
    # the imaginary axis up to sqrt(3), and the half-disc within it
    assert abs(stability_radius(diffrax.Bosh3()) - np.sqrt(3.0)) <= GRID
    # Heun: R = 1 + z + z^2/2, |R(iy)|^2 = 1 + y^4/4 <= (1 + 1e-3)^2
    heun = (4.0 * ((1.0 + 1e-3) ** 2 - 1.0)) ** 0.25
    assert abs(stability_radius(diffrax.Heun()) - heun) <= GRID
    assert stability_radius(diffrax.Kvaerno5()) == np.inf  # implicit: no bound


def _stability_polynomial(tableau):
    s = len(tableau.b_sol)
    A = np.zeros((s, s))
    for i, row in enumerate(tableau.a_lower):
        A[i + 1, : i + 1] = row
    return lambda z: (
        1
        + z * np.asarray(tableau.b_sol) @ np.linalg.solve(np.eye(s) - z * A, np.ones(s))
    )


@pytest.mark.parametrize(
    "solver", [diffrax.Tsit5(), diffrax.Dopri5(), diffrax.Dopri8()]
)
def test_stability_radius_bounds_the_growth_on_the_half_disc(solver):
    """|R| <= 1 + 1e-3 on the half-disc of the radius (R from its resolvent form,
    not the polynomial the module sums), and above it just beyond."""
    R = _stability_polynomial(solver.tableau)
    r = stability_radius(solver)
    angles = np.linspace(np.pi / 2, 3 * np.pi / 2, 181)
    inside = [
        abs(R(rho * np.exp(1j * a))) for rho in np.linspace(0, r, 40) for a in angles
    ]
    assert max(inside) <= 1 + 1e-3 + 1e-12
    beyond = [abs(R((r + 2 * GRID) * np.exp(1j * a))) for a in angles]
    assert max(beyond) > 1 + 1e-3


@pytest.mark.parametrize("convention", ["zxz", "rpy"])
def test_rate_bound_holds_and_is_close(convention):
    model = three_body_model(convention)
    turned = three_body_state(convention).at[:, 3:].add(jnp.array([0.3, -0.2, 0.4]))
    moved = turned.at[1, :3].add(jnp.array([0.05, -0.03, 0.02]))  # links loaded
    immobile = eo.linearize_mobile(model, three_body_state(convention))
    for m, y in ((model, turned), (model, moved), (immobile, turned)):
        exact = exact_rate(m, y)  # NumPy's eigenvalues of the first-order form
        bound = float(jax.jit(linear_rate_bound)(m, y))
        assert exact <= bound * (1 + 1e-12)
        assert bound < 2.0 * exact


@pytest.mark.slow  # three programs: the run, its gradient and its forward mode
def test_gradients_of_a_run_at_rest_are_the_central_differences():
    model, y0, holding = beam_at_rest()
    ts = jnp.linspace(0.0, 0.3, 7)

    def end_x(y, adjoint=None):
        return eo.simulate(
            model, y, jnp.zeros_like(y), ts, forces=holding, adjoint=adjoint
        ).y[-1, 0, 0]

    h = 1e-6
    central = (end_x(y0.at[0, 0].add(h)) - end_x(y0.at[0, 0].add(-h))) / (2 * h)
    assert 0.5 < float(central) < 1.0  # the beam follows its start, springing back
    reverse = jax.grad(end_x)(y0)[0, 0]
    forward = jax.jacfwd(lambda y: end_x(y, diffrax.ForwardMode()))(y0)[0, 0]
    for derivative in (reverse, forward):
        np.testing.assert_allclose(float(derivative), float(central), rtol=1e-7)
