"""A smoothing differentiator: Savitzky-Golay (local least-squares polynomial) fits.

At each sample $t_k$ a polynomial of degree `polyorder` is fitted by least squares
to the `window` samples centred on $t_k$ (uniform spacing $h$), and its value and
derivatives at $t_k$ are taken as the estimates. The estimate is a fixed linear
filter of the samples (Savitzky & Golay, Anal. Chem. 36 (1964) 1627): it
differentiates polynomials of degree <= `polyorder` exactly and smooths away
noise at frequencies well above the window's reciprocal length, so the window
should span clearly less than one period of the fastest mode in the data.
Near the ends the polynomial fitted to the first (last) `window` samples is
evaluated off-centre. The filter is `scipy.signal.savgol_filter(mode="interp")`;
this module adds the checks on the sampling and the window.
"""

import numpy as np
from scipy.signal import savgol_filter


def savitzky_golay(
    values, ts, window: int = 21, polyorder: int = 4, derivs=(0, 1, 2)
) -> tuple:
    """Smoothed values and derivatives of uniformly sampled data.

    **Arguments:**

    - `values`: samples, shape `(times, ...)`; NaN samples make the estimates whose
      window contains them NaN.
    - `ts`: uniformly spaced sample times, shape `(times,)`.
    - `window`: odd number of samples in each local fit (> `polyorder`).
    - `polyorder`: degree of the local polynomial (>= the highest derivative).
    - `derivs`: which derivatives to return (0 = smoothed values).

    **Returns:** a tuple with one array shaped like `values` per entry of `derivs`.
    """
    values = np.asarray(values, dtype=np.float64)
    ts = np.asarray(ts, dtype=np.float64)
    n = ts.shape[0]
    if values.shape[:1] != (n,):
        raise ValueError(
            f"values must have {n} samples along axis 0 like ts, got shape "
            f"{values.shape}"
        )
    if not (isinstance(window, int) and window % 2 == 1 and window >= 3):
        raise ValueError(f"window must be an odd integer >= 3, got {window!r}")
    if not (isinstance(polyorder, int) and 0 <= polyorder < window):
        raise ValueError(
            f"polyorder must be an integer in [0, window), got {polyorder!r}"
        )
    if max(derivs) > polyorder:
        raise ValueError(
            f"polyorder = {polyorder} cannot estimate derivative {max(derivs)}"
        )
    if n < window:
        raise ValueError(
            f"the smoothing window ({window} samples) is longer than the data "
            f"({n} samples): choose a smaller window"
        )
    h = np.diff(ts)
    step = float(np.mean(h))
    if np.max(np.abs(h - step)) > 1e-6 * step:
        raise ValueError(
            "the smoothing differentiator needs uniformly spaced samples ts; "
            "resample the data or pass measured ydot/yddot"
        )
    flat = values.reshape(n, -1)
    missing = np.isnan(flat)
    filled = np.where(missing, 0.0, flat)
    spoilt = _windows_with(missing, window)
    out = []
    for d in derivs:
        est = savgol_filter(
            filled, window, polyorder, deriv=d, delta=step, axis=0, mode="interp"
        )
        out.append(np.where(spoilt, np.nan, est).reshape(values.shape))
    return tuple(out)


def _windows_with(missing, window: int):
    """Whether the samples each estimate is fitted to (the `window` samples centred
    on it; the first or last `window` near the ends) include a missing one."""
    n, half = missing.shape[0], window // 2
    counts = np.concatenate(
        [np.zeros((1, missing.shape[1])), np.cumsum(missing, axis=0)]
    )
    k = np.arange(n)
    lo = np.clip(k - half, 0, n - window)  # the first sample of each window
    return (counts[lo + window] - counts[lo]) > 0
