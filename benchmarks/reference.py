"""Hand-written references of the MobileModel dynamics (Appendix B).

Two independent hand derivations of $W(Y)\\ddot Y + w(Y, \\dot Y) = G + F$, used to
check the library's autodiff right-hand side and to measure how fast it could be:

- `numpy_rhs`: plain NumPy, what a researcher would write from the appendix: per body
  the printed $W_i$ and angular rows of $w_i$ (ZXZ, with corrections 2 and 3 of
  docs/model.md), or $W_{rot} = L_\\omega^T I L_\\omega$ and
  $L_\\omega^T (I \\dot L_\\omega \\dot{\\mathcal A} + \\omega \\times I\\omega)$ (RPY),
  a loop over connections, and `np.linalg.solve` per body. `solve_ivp_mobile`
  integrates it with `scipy.integrate.solve_ivp`.
- `fast_jax_rhs`: JAX written for speed (the limit the library is measured against):
  the rotational block inverted in closed form,
  $W_{rot}^{-1} = L_\\omega^{-1} I^{-1} L_\\omega^{-T}$ (Euler's equations
  $I\\dot\\omega + \\omega\\times I\\omega = \\tau$, $\\tau = L_\\omega^{-T} Q$,
  $\\ddot{\\mathcal A} =
  L_\\omega^{-1}(\\dot\\omega - \\dot L_\\omega\\dot{\\mathcal A})$),
  the deflection Jacobian $\\mathcal G = s I + (\\rho_0/|d|) n n^T$ applied as a
  rank-one update, per-body sums by a gather with indices fixed at trace time (no
  scatter-add), and every sine and cosine computed once.

Both take the parameters from `numpy_params(model)`. Import with the `benchmarks`
folder on `sys.path` (`import reference`).
"""

import jax.numpy as jnp
import numpy as np
import scipy.integrate


def numpy_params(model) -> dict:
    """NumPy copies of a `MobileModel`'s parameters.

    **Returns:** a dict with `masses` `(n,)`, `inertias` `(n, 3)`, `pairs` `(P, 2)`
    int, `stiffness` and `damping` `(P, 6)`, `rest_length` `(P,)`, `rest_angles`
    `(P, 3)`, `gravity` (float) and `convention` (`"zxz"` or `"rpy"`).
    """
    return {
        "masses": np.asarray(model.bodies.mass, dtype=np.float64),
        "inertias": np.asarray(model.bodies.inertia, dtype=np.float64),
        "pairs": np.asarray(model.pairs, dtype=np.int64).reshape(-1, 2),
        "stiffness": np.asarray(model.stiffness, dtype=np.float64).reshape(-1, 6),
        "damping": np.asarray(model.damping, dtype=np.float64).reshape(-1, 6),
        "rest_length": np.asarray(model.rest_length, dtype=np.float64).reshape(-1),
        "rest_angles": np.asarray(model.rest_angles, dtype=np.float64).reshape(-1, 3),
        "gravity": float(model.gravity),
        "convention": model.convention,
    }


def _full_force(force, n):
    """`(n, 6)` generalized forces from None, `(n - 1, 6)` or `(n, 6)`."""
    if force is None:
        return np.zeros((n, 6))
    force = np.asarray(force, dtype=np.float64)
    if force.shape == (n - 1, 6):
        return np.concatenate([np.zeros((1, 6)), force])
    if force.shape != (n, 6):
        raise ValueError(f"force must have shape ({n - 1}, 6) or ({n}, 6)")
    return force


# --------------------------------------------------------------------------- NumPy


def _zxz_rotational(A, B, C, angles, rates):
    """The appendix's $W_i$ angular block and angular rows of $w_i$ (ZXZ)."""
    _, theta, phi = angles
    dpsi, dtheta, dphi = rates
    st, ct = np.sin(theta), np.cos(theta)
    sp, cp = np.sin(phi), np.cos(phi)
    s2p, c2p = np.sin(2 * phi), np.cos(2 * phi)
    W = np.array(
        [
            [
                st**2 * (A * sp**2 + B * cp**2) + C * ct**2,
                0.5 * (A - B) * st * s2p,
                C * ct,
            ],
            [0.5 * (A - B) * st * s2p, A * cp**2 + B * sp**2, 0.0],
            [C * ct, 0.0, C],
        ]
    )
    w = np.array(
        [
            dpsi * dtheta * np.sin(2 * theta) * (A * sp**2 + B * cp**2 - C)
            + dpsi * dphi * (A - B) * st**2 * s2p
            + dtheta * dphi * st * ((A - B) * c2p - C)
            + 0.5 * dtheta**2 * (A - B) * ct * s2p,
            -0.5 * dpsi**2 * np.sin(2 * theta) * (A * sp**2 + B * cp**2 - C)
            + dpsi * dphi * st * ((A - B) * c2p + C)
            - dtheta * dphi * (A - B) * s2p,
            -0.5 * dpsi**2 * (A - B) * st**2 * s2p
            - dpsi * dtheta * st * ((A - B) * c2p + C)
            + 0.5 * dtheta**2 * (A - B) * s2p,
        ]
    )
    return W, w


def _rpy_rotational(A, B, C, angles, rates):
    """$W_{rot} = L^T I L$ and
    $L^T(I\\dot L\\dot{\\mathcal A} + \\omega\\times I\\omega)$ for roll-pitch-yaw
    angles."""
    roll, pitch, _ = angles
    droll, dpitch, dyaw = rates
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    L = np.array([[1.0, 0.0, -sp], [0.0, cr, sr * cp], [0.0, -sr, cr * cp]])
    Ldot = np.array(
        [
            [0.0, 0.0, -cp * dpitch],
            [0.0, -sr * droll, cr * cp * droll - sr * sp * dpitch],
            [0.0, -cr * droll, -sr * cp * droll - cr * sp * dpitch],
        ]
    )
    inertia = np.diag([A, B, C])
    omega = L @ rates
    W = L.T @ inertia @ L
    w = L.T @ (inertia @ (Ldot @ rates) + np.cross(omega, inertia @ omega))
    return W, w


def numpy_rhs(params, y, ydot, force=None):
    """$\\ddot Y$ of the MobileModel in plain NumPy.

    **Arguments:** `params` from `numpy_params`; `y`, `ydot` of shape `(n, 6)`;
    `force`: `None`, `(n - 1, 6)` on the contact bodies or `(n, 6)`.

    **Returns:** `yddot`, shape `(n, 6)`.
    """
    y = np.asarray(y, dtype=np.float64)
    ydot = np.asarray(ydot, dtype=np.float64)
    n = y.shape[0]
    Q = _full_force(force, n).copy()
    Q[:, 2] -= params["gravity"] * params["masses"]
    for k, (i, j) in enumerate(params["pairs"]):
        d = y[i, :3] - y[j, :3]
        ddot = ydot[i, :3] - ydot[j, :3]
        length = np.linalg.norm(d)
        rho = params["rest_length"][k]
        unit = d / length
        G = (1 - rho / length) * np.eye(3) + (rho / length) * np.outer(unit, unit)
        delta = (1 - rho / length) * d
        c, b = params["stiffness"][k], params["damping"][k]
        link = G.T @ (c[:3] * delta) + G.T @ (b[:3] * (G @ ddot))
        angle = c[3:] * (y[i, 3:] - y[j, 3:] - params["rest_angles"][k]) + b[3:] * (
            ydot[i, 3:] - ydot[j, 3:]
        )
        wrench = np.concatenate([link, angle])  # dPi/dY_i + dR/dYdot_i
        Q[i] -= wrench
        Q[j] += wrench
    rotational = _zxz_rotational if params["convention"] == "zxz" else _rpy_rotational
    yddot = np.empty((n, 6))
    for b in range(n):
        A, B, C = params["inertias"][b]
        W_rot, w_rot = rotational(A, B, C, y[b, 3:], ydot[b, 3:])
        W = np.zeros((6, 6))
        W[:3, :3] = params["masses"][b] * np.eye(3)
        W[3:, 3:] = W_rot
        w = np.concatenate([np.zeros(3), w_rot])
        yddot[b] = np.linalg.solve(W, Q[b] - w)
    return yddot


def solve_ivp_mobile(
    model,
    y_init,
    ydot_init,
    ts,
    force=None,
    rtol=1e-8,
    atol=1e-10,
    method="RK45",
):
    """Integrate the NumPy right-hand side with `scipy.integrate.solve_ivp`.

    **Arguments:** a `MobileModel`; `y_init`, `ydot_init` `(n, 6)`; output times
    `ts`; `force`: `None`, a constant array `(n - 1, 6)` / `(n, 6)`, or a callable
    `f(t, y, ydot) -> array` on NumPy arrays; tolerances and method of `solve_ivp`.

    **Returns:** $Y$ at `ts`, shape `(len(ts), n, 6)`.
    """
    params = numpy_params(model)
    y_init = np.asarray(y_init, dtype=np.float64)
    n = y_init.shape[0]
    size = 6 * n

    def rhs(t, state):
        y = state[:size].reshape(n, 6)
        ydot = state[size:].reshape(n, 6)
        f = force(t, y, ydot) if callable(force) else force
        return np.concatenate([ydot.reshape(-1), numpy_rhs(params, y, ydot, f).ravel()])

    ts = np.asarray(ts, dtype=np.float64)
    state0 = np.concatenate([y_init.ravel(), np.asarray(ydot_init).ravel()])
    sol = scipy.integrate.solve_ivp(
        rhs, (ts[0], ts[-1]), state0, method=method, t_eval=ts, rtol=rtol, atol=atol
    )
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    return sol.y[:size].T.reshape(len(ts), n, 6)


# ----------------------------------------------------------------------------- JAX


def _incidence(pairs, n):
    """Static per-body gather of connection wrenches: indices `(n, K)` and signs
    (+1 where the body is the connection's first end, -1 second, 0 padding)."""
    rows = [[] for _ in range(n)]
    for k, (i, j) in enumerate(pairs):
        rows[i].append((k, 1.0))
        rows[j].append((k, -1.0))
    width = max(1, max((len(r) for r in rows), default=1))
    index = np.zeros((n, width), dtype=np.int64)
    sign = np.zeros((n, width))
    for b, row in enumerate(rows):
        for slot, (k, s) in enumerate(row):
            index[b, slot], sign[b, slot] = k, s
    return index, sign


def fast_jax_rhs(params, y, ydot, force=None):
    """$\\ddot Y$ of the MobileModel in JAX, written for speed (see the module doc).

    **Arguments:** `params` from `numpy_params` (its NumPy arrays become constants
    of the compiled function, so connectivity is fixed at trace time); `y`, `ydot`
    `(n, 6)`; `force`: `None`, `(n - 1, 6)` or `(n, 6)`. `jax.jit`/`jax.vmap` it
    with `params` closed over.

    **Returns:** `yddot`, shape `(n, 6)`.
    """
    n = y.shape[0]
    pairs = params["pairs"]
    mass = jnp.asarray(params["masses"])
    A, B, C = (jnp.asarray(params["inertias"][:, k]) for k in range(3))

    # Generalized force Q = G + F - dPi/dY - dR/dYdot.
    if force is None:
        Q = jnp.zeros((n, 6))
    elif force.shape[0] == n - 1:
        Q = jnp.concatenate([jnp.zeros((1, 6)), force])
    else:
        Q = force
    gravity = np.zeros((n, 6))
    gravity[:, 2] = -params["gravity"] * params["masses"]
    Q = Q + gravity
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        c, b = params["stiffness"], params["damping"]
        rho = params["rest_length"]
        d = y[i, :3] - y[j, :3]
        ddot = ydot[i, :3] - ydot[j, :3]
        inv_len = 1.0 / jnp.sqrt(jnp.sum(d * d, axis=-1, keepdims=True))
        ratio = rho[:, None] * inv_len  # rho0/|d|
        s = 1.0 - ratio
        unit = d * inv_len
        # G v = s v + (rho0/|d|) n (n . v): rank-one update, G symmetric.
        rate = s * ddot + ratio * unit * jnp.sum(unit * ddot, axis=-1, keepdims=True)
        u = c[:, :3] * (s * d) + b[:, :3] * rate
        link = s * u + ratio * unit * jnp.sum(unit * u, axis=-1, keepdims=True)
        angle = c[:, 3:] * (y[i, 3:] - y[j, 3:] - params["rest_angles"]) + b[:, 3:] * (
            ydot[i, 3:] - ydot[j, 3:]
        )
        wrench = jnp.concatenate([link, angle], axis=-1)  # on the first end i
        index, sign = _incidence(pairs, n)
        Q = Q - jnp.sum(wrench[index] * sign[..., None], axis=1)

    lin = Q[:, :3] / mass[:, None]
    a1, a2, a3 = ydot[:, 3], ydot[:, 4], ydot[:, 5]
    q1, q2, q3 = Q[:, 3], Q[:, 4], Q[:, 5]
    if params["convention"] == "zxz":
        st, ct = jnp.sin(y[:, 4]), jnp.cos(y[:, 4])
        sp, cp = jnp.sin(y[:, 5]), jnp.cos(y[:, 5])
        # omega = L a', and Ldot a' (the part of omega' without a'').
        w1 = a1 * st * sp + a2 * cp
        w2 = a1 * st * cp - a2 * sp
        w3 = a1 * ct + a3
        l1 = a1 * (ct * a2 * sp + st * cp * a3) - a2 * sp * a3
        l2 = a1 * (ct * a2 * cp - st * sp * a3) - a2 * cp * a3
        l3 = -a1 * st * a2
        # tau = L^-T Q.
        inv_st = 1.0 / st
        p = (q1 - ct * q3) * inv_st
        t1, t2, t3 = sp * p + cp * q2, cp * p - sp * q2, q3
    else:
        sr, cr = jnp.sin(y[:, 3]), jnp.cos(y[:, 3])
        sp, cp = jnp.sin(y[:, 4]), jnp.cos(y[:, 4])
        w1 = a1 - sp * a3
        w2 = cr * a2 + sr * cp * a3
        w3 = -sr * a2 + cr * cp * a3
        l1 = -cp * a2 * a3
        l2 = -sr * a1 * a2 + (cr * a1 * cp - sr * sp * a2) * a3
        l3 = -cr * a1 * a2 - (sr * a1 * cp + cr * sp * a2) * a3
        inv_cp = 1.0 / cp
        p = (q3 + sp * q1) * inv_cp
        t1, t2, t3 = q1, cr * q2 + sr * p, -sr * q2 + cr * p
    # Euler: I omega' = tau - omega x I omega; then e = omega' - Ldot a' = L a''.
    e1 = (t1 - (C - B) * w2 * w3) / A - l1
    e2 = (t2 - (A - C) * w3 * w1) / B - l2
    e3 = (t3 - (B - A) * w1 * w2) / C - l3
    if params["convention"] == "zxz":
        dd1 = (e1 * sp + e2 * cp) * inv_st
        dd2 = e1 * cp - e2 * sp
        dd3 = e3 - ct * dd1
    else:
        dd3 = (sr * e2 + cr * e3) * inv_cp
        dd2 = cr * e2 - sr * e3
        dd1 = e1 + sp * dd3
    return jnp.concatenate([lin, jnp.stack([dd1, dd2, dd3], axis=-1)], axis=-1)
