"""Which grasp stiffnesses and dampings of an estimate the samples can resolve.

A connection $k$ between bodies $i$ and $j$ moves along each axis $a$ like an
oscillator of the reduced inertia $\\mu_{ka} = I_i I_j / (I_i + I_j)$ ($I$ the
masses along $x, y, z$, the principal moments of inertia about the three angle
axes). Sampled every $\\Delta t$, the data resolve motion slower than their
Nyquist frequency $\\pi / \\Delta t$ and relaxation over at least part of a sample
interval. A stiffness whose natural frequency $\\sqrt{c / \\mu}$ is above
`RESOLUTION` times the Nyquist frequency, or a damping whose relaxation time
$\\mu / d$ is below $\\Delta t$ / `RESOLUTION`, describes motion the samples cannot
show: the data cannot tell such a value from any larger one. The equation-error
estimate (a linear least-squares fit to second differences of noisy samples) can
land there by amplifying the noise, and a fit started there simulates a stiff
system (many solver steps) far from the minimum.
"""

import numpy as np

from .._models import MobileModel

# How far beyond what the samples resolve a value must be to be implausible.
RESOLUTION = 10.0


def unresolved(model, dt: float):
    """Boolean arrays shaped like `model.stiffness` and `model.damping`: the
    entries beyond what samples every `dt` seconds resolve (see the module
    docstring). `None` for a model other than a `MobileModel` (an immobile
    model's stiffness matrix has no connection per entry)."""
    if not isinstance(model, MobileModel):
        return None
    pairs = np.asarray(model.pairs, dtype=int)
    mass = np.asarray(model.bodies.mass, dtype=np.float64)
    inertia = np.asarray(model.bodies.inertia, dtype=np.float64)
    per_axis = np.concatenate([np.repeat(mass[:, None], 3, axis=1), inertia], axis=1)
    a, b = per_axis[pairs[:, 0]], per_axis[pairs[:, 1]]
    mu = a * b / (a + b)
    c = np.asarray(model.stiffness, dtype=np.float64)
    d = np.asarray(model.damping, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        stiff = np.sqrt(np.maximum(c, 0.0) / mu) > RESOLUTION * np.pi / dt
        damped = mu / d < dt / RESOLUTION
    return stiff, damped & (d > 0)
