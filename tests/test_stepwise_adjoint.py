"""`StepwiseAdjoint` against diffrax's adjoint (an independent implementation of
the discrete adjoint of the same solution) and central differences."""

import functools

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import Wave, three_body_model, three_body_state

import elasticoop as eo
from elasticoop._integrate.recorder import StepLayout

MODEL = three_body_model()
Y0 = three_body_state().at[1, :3].add(jnp.array([-0.01, 0.005, 0.01]))
Y0 = Y0.at[2, 3:].add(jnp.array([0.02, -0.01, 0.03]))
YDOT0 = jnp.zeros_like(Y0).at[0, :3].set(jnp.array([0.1, 0.0, 0.2]))
LIFT = jnp.zeros((3, 6)).at[1:, 2].set(12.0)
TS = jnp.linspace(0.0, 0.2, 21)
TOL = dict(rtol=1e-10, atol=1e-12)
# The two adjoints take the same steps and the same products, in another order:
# they differ by rounding (at most 5e-14 measured, Bosh3's many steps).
RTOL = 1e-12
# diffrax's adjoint, what the stepwise adjoint is compared with
CHECKPOINTS = diffrax.RecursiveCheckpointAdjoint()


def swaying_grasps():
    mask = np.zeros((3, 6), dtype=bool)
    mask[1:, :] = True  # the grasps follow a swaying motion
    amplitude = jnp.zeros((3, 6)).at[1:, 2].set(0.01).at[1:, 4].set(0.02)
    return eo.PrescribedMotion(mask, Wave(Y0, amplitude))


def loss_and_outcome(params, adjoint, solver=None, prescribed=None, max_steps=100_000):
    """Weighted squares of every output (all states, rates, work, dissipation),
    as a function of stiffness, damping, masses, initial state and forces; and the
    run's outcome: its status, number of steps and which outputs it reached."""
    stiffness, damping, mass, y0, force = params
    model = eqx.tree_at(
        lambda m: (m.stiffness, m.damping, m.bodies.mass),
        MODEL,
        (stiffness, damping, mass),
    )
    traj = eo.simulate(
        model,
        y0,
        YDOT0,
        TS,
        forces=force,
        options=eo.SimulationOptions(
            diffrax.Tsit5() if solver is None else solver, max_steps=max_steps, **TOL
        ),
        adjoint=adjoint,
        prescribed=prescribed,
        throw=False,
    )
    weights = jnp.arange(1.0, 1.0 + TS.shape[0])[:, None, None]
    # (a run that stops early has NaN at the outputs it did not reach)
    reached = jnp.all(jnp.isfinite(traj.y), axis=(1, 2))
    y = jnp.where(reached[:, None, None], traj.y, 0.0)
    ydot = jnp.where(reached[:, None, None], traj.ydot, 0.0)
    value = (
        jnp.sum(weights * (y - Y0[None]) ** 2)
        + jnp.sum(weights * ydot**2)
        + jnp.sum(jnp.where(reached, traj.work + traj.dissipated, 0.0))
    )
    return value, (traj.status, traj.n_steps, reached)


def loss(params, adjoint, **kwargs):
    """The loss of `loss_and_outcome` alone."""
    return loss_and_outcome(params, adjoint, **kwargs)[0]


PARAMS = (MODEL.stiffness, MODEL.damping, MODEL.bodies.mass, Y0, LIFT)


def gradient(adjoint, **kwargs):
    """The loss's gradient with respect to the parameters (by `adjoint`), and the
    outcome of the run differentiated."""
    return jax.grad(lambda p: loss_and_outcome(p, adjoint, **kwargs), has_aux=True)


def compiled_gradient(adjoint, solver=None, prescribed=False, max_steps=100_000):
    """`gradient` jitted, once per adjoint and settings for all the tests of this
    file (each program takes seconds to compile). `prescribed`: whether the grasps
    follow `swaying_grasps`."""
    return _compiled_gradient(adjoint, solver, prescribed, max_steps)


@functools.cache  # (its arguments in one form, however they were passed)
def _compiled_gradient(adjoint, solver, prescribed, max_steps):
    motion = swaying_grasps() if prescribed else None
    return jax.jit(
        gradient(adjoint, solver=solver, prescribed=motion, max_steps=max_steps)
    )


def gradients(**settings):
    """The gradients at `PARAMS` by both adjoints (each with its run's outcome)."""
    ours = compiled_gradient(eo.StepwiseAdjoint(), **settings)(PARAMS)
    theirs = compiled_gradient(CHECKPOINTS, **settings)(PARAMS)
    return ours, theirs


def assert_close(ours, theirs, rtol=RTOL):
    for name, a, b in zip(
        ("stiffness", "damping", "mass", "y0", "forces"), ours, theirs, strict=True
    ):
        scale = float(jnp.max(jnp.abs(b)))
        assert scale > 0, name
        gap = float(jnp.max(jnp.abs(a - b))) / scale
        assert gap < rtol, (name, gap)


@pytest.mark.slow
def test_equals_diffrax_adjoint_and_central_differences():
    (ours, _), (theirs, _) = gradients()
    assert_close(ours, theirs)
    # and one entry against central differences (the loss's rounding limits it)
    h = 1e-4 * float(MODEL.stiffness[0, 2])
    e = jnp.zeros_like(MODEL.stiffness).at[0, 2].set(h)
    up = loss((PARAMS[0] + e, *PARAMS[1:]), None)
    down = loss((PARAMS[0] - e, *PARAMS[1:]), None)
    np.testing.assert_allclose(ours[0][0, 2], (up - down) / (2 * h), rtol=1e-5)


@pytest.mark.slow
@pytest.mark.parametrize(
    "solver", [diffrax.Dopri5(), diffrax.Dopri8(), diffrax.Bosh3()], ids=type
)
def test_other_explicit_solvers(solver):
    """Each solver's own tableau and dense output (Bosh3: cubic Hermite)."""
    (ours, _), (theirs, _) = gradients(solver=solver)
    assert_close(ours, theirs)


@pytest.mark.slow
def test_sampled_force_with_a_jump_time():
    """A `SampledForce` whose slope changes at 0.1 s: the controller ends a step
    there (a jump time), and the steps are replayed with the times they took. Its
    samples are differentiated (its times and jump times are not)."""
    times = jnp.linspace(0.0, 0.2, 5)
    ramp = 1.0 + jnp.minimum(times, 0.1) / 0.1
    samples = ramp[:, None, None] * LIFT[None]
    force = eo.SampledForce(times, samples, jump_ts=[0.1])

    def of_samples(samples, adjoint):
        sampled = eqx.tree_at(lambda f: f.F, force, samples)
        return loss((*PARAMS[:4], sampled), adjoint)

    ours = jax.jit(jax.grad(lambda F: of_samples(F, eo.StepwiseAdjoint())))(samples)
    theirs = jax.jit(jax.grad(lambda F: of_samples(F, CHECKPOINTS)))(samples)
    gap = float(jnp.max(jnp.abs(ours - theirs)) / jnp.max(jnp.abs(theirs)))
    assert gap < RTOL, gap


@pytest.mark.slow
def test_prescribed_motion():
    (ours, _), (theirs, _) = gradients(prescribed=True)
    assert_close(ours, theirs)


@pytest.mark.slow
@pytest.mark.parametrize("prescribed", [False, True], ids=["free", "prescribed"])
def test_run_stopped_before_the_end(prescribed):
    """A run that ends at its step limit: its end state is saved after the
    outputs it reached (the slots after it, inf, have no cotangent; with
    prescribed motion `simulate` evaluates the motion there too), the outputs
    enter through the steps taken. (The run differentiated is checked to stop at
    its limit with some but not all outputs reached.)"""
    (ours, outcome), (theirs, _) = gradients(max_steps=40, prescribed=prescribed)
    assert_close(ours, theirs)
    status, _, reached = outcome
    assert status == eo.Status.MAX_STEPS_REACHED
    assert 1 < int(reached.sum()) < TS.shape[0]


def test_unsupported_solver_is_refused():
    with pytest.raises(ValueError, match="StepwiseAdjoint needs an explicit"):
        eo.simulate(
            MODEL,
            Y0,
            YDOT0,
            TS,
            options=eo.SimulationOptions(diffrax.Kvaerno5()),
            adjoint=eo.StepwiseAdjoint(),
        )


@pytest.mark.slow
def test_output_times_are_not_differentiated():
    def final_height(ts):
        traj = eo.simulate(
            MODEL, Y0, YDOT0, ts, adjoint=eo.StepwiseAdjoint(), throw=False
        )
        return traj.y[-1, 0, 2]

    # (asked for explicitly; the default falls back on diffrax's adjoint)
    with pytest.raises(ValueError, match="output times ts"):
        jax.jit(jax.grad(final_height))(TS)


def test_step_layout_keeps_each_kept_step_once():
    """Every step at most once; the first `kept` all, then every 2nd, 4th, ...;
    each step's checkpoint is the last kept step at or before it."""
    layout = StepLayout.of(max_steps=1000, kept=64)
    assert layout.levels == 5  # 64 * (2**5 - 1) = 1984 >= 1000 > 64 * (2**4 - 1)
    steps = np.arange(1000, dtype=np.int32)
    slots = np.asarray(jax.vmap(layout.slot)(jnp.asarray(steps)))
    kept = slots != layout.spare
    assert np.all(kept[:64])
    assert np.all(kept[64:192:2]) and not np.any(kept[65:192:2])
    assert np.all(kept[192:448:4]) and not np.any(kept[193:448:4])
    assert len(set(slots[kept])) == kept.sum()
    assert slots[kept].max() < layout.spare
    start, slot = map(np.asarray, jax.vmap(layout.checkpoint)(jnp.asarray(steps)))
    expected = np.maximum.accumulate(np.where(kept, steps, 0))
    np.testing.assert_array_equal(start, expected)
    np.testing.assert_array_equal(slot, slots[start])
    # a run shorter than `kept` keeps every step
    assert StepLayout.of(max_steps=40, kept=2048) == StepLayout(40, 1, 40)


@pytest.mark.parametrize("kept", [0, 63, True])
def test_kept_steps_is_checked(kept):
    with pytest.raises(
        ValueError, match=f"kept_steps must be an integer >= 64, got {kept!r}"
    ):
        eo.StepwiseAdjoint(kept_steps=kept)


@pytest.mark.slow
def test_steps_past_the_kept_ones_are_replayed():
    """With `kept_steps=64` the run's steps past the 64th keep every 2nd, 4th and
    8th start state; the backward pass replays the others from them."""
    adjoint = eo.StepwiseAdjoint(kept_steps=64)
    ours, (status, n_steps, _) = compiled_gradient(adjoint, max_steps=1000)(PARAMS)
    assert status == eo.Status.SUCCESS
    assert int(n_steps) > 64 * (2**3 - 1)  # into the fourth level
    theirs, _ = compiled_gradient(CHECKPOINTS)(PARAMS)
    assert_close(ours, theirs)


@pytest.mark.slow
@pytest.mark.parametrize("max_steps", [100_000, 40], ids=["to_the_end", "stopped"])
def test_vmap_of_gradients(max_steps):
    """Under `jax.vmap` the forward half runs in the batch loop, which writes the
    record of the steps in place, and the backward pass loops over blocks of
    steps. Each sample's gradient equals diffrax's adjoint's of that sample alone
    to within the solver's tolerance (the batch loop takes the same steps, each
    equal to rounding); with `kept_steps=64` the replay of start states not kept
    runs batched too; at `max_steps=40` each run stops early, its last slots
    written by the batch loop after it stopped."""
    stiffness = PARAMS[0][None] * jnp.array([1.0, 1.3, 0.8])[:, None, None]
    in_axes = ((0, None, None, None, None),)
    adjoint = eo.StepwiseAdjoint(kept_steps=64)
    batch = jax.jit(jax.vmap(gradient(adjoint, max_steps=max_steps), in_axes))
    ours, _ = batch((stiffness, *PARAMS[1:]))
    single = compiled_gradient(CHECKPOINTS, max_steps=max_steps)
    for i in range(stiffness.shape[0]):
        theirs, _ = single((stiffness[i], *PARAMS[1:]))
        assert_close([g[i] for g in ours], theirs, rtol=1e-9)


@pytest.mark.slow
def test_the_default_adjoint_is_stepwise_with_diffrax_for_the_rest():
    """`adjoint=None`: the stepwise adjoint for an explicit Runge-Kutta solver
    (the same gradient program, so the same gradients bitwise), and diffrax's
    adjoint for a gradient with respect to the output times, which the stepwise
    adjoint holds fixed."""

    def program(adjoint):
        """The gradient's program as lowered for XLA (before compiling it)."""
        return compiled_gradient(adjoint).lower(PARAMS).as_text()

    default = program(None)
    assert default == program(eo.StepwiseAdjoint())
    assert default != program(CHECKPOINTS)

    def final_height(ts, adjoint):
        options = eo.SimulationOptions("tsit5", **TOL)
        traj = eo.simulate(
            MODEL, Y0, YDOT0, ts, options=options, adjoint=adjoint, throw=False
        )
        return traj.y[-1, 0, 2]

    gradient_of_ts = jax.jit(jax.grad(final_height), static_argnums=1)
    ours = gradient_of_ts(TS, None)
    theirs = gradient_of_ts(TS, CHECKPOINTS)
    assert float(jnp.max(jnp.abs(theirs))) > 0
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-15)
