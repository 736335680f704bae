"""Probability distributions of uncertain parameters, written as inverse CDFs.

Every built-in distribution maps a uniform variate $u \\in (0, 1)$ to a value by its
inverse cumulative distribution function (`ppf`), so plain random sampling and Latin
hypercube sampling share one code path: only the way $u$ is drawn differs. The
distribution's parameters broadcast against the shape of the model leaf it is
assigned to (e.g. one standard deviation per stiffness entry, or one for all).
"""

import abc
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.special as jss
import numpy as np

from .._validation import as_float_array


def _param(value, name: str):
    return jnp.asarray(as_float_array(value, name))


def _check(ok, message: str, value) -> None:
    if not bool(np.all(np.asarray(ok))):
        raise ValueError(f"{message}, got {np.asarray(value).tolist()}")


class AbstractDistribution(eqx.Module):
    """The law of one uncertain model leaf.

    Subclasses implement `sample`, `ppf`, `supports_ppf` and `describe`. The
    built-in laws derive from `AbstractInverseCDFDistribution`, which samples through
    the inverse CDF; `Custom` wraps a user's sampler."""

    @abc.abstractmethod
    def sample(self, key, shape) -> jax.Array:
        """Draw one value of the given shape from `key`."""

    @abc.abstractmethod
    def ppf(self, u) -> jax.Array:
        """Inverse CDF at $u \\in (0, 1)$ (needed for Latin hypercube sampling)."""

    @property
    @abc.abstractmethod
    def supports_ppf(self) -> bool:
        """Whether `ppf` is available (and so Latin hypercube sampling)."""

    @abc.abstractmethod
    def describe(self) -> dict:
        """A JSON-able description (recorded in the study's manifest)."""


class AbstractInverseCDFDistribution(AbstractDistribution):
    """A law given by its inverse CDF: `sample` draws $u \\sim U(0, 1)$ and returns
    `ppf(u)`, so random and Latin hypercube sampling share one code path."""

    def sample(self, key, shape) -> jax.Array:
        tiny = jnp.finfo(jnp.float64).tiny
        return self.ppf(jax.random.uniform(key, shape, minval=tiny, maxval=1.0))

    @property
    def supports_ppf(self) -> bool:
        return True


class Uniform(AbstractInverseCDFDistribution):
    """Uniform on $[\\text{low}, \\text{high}]$: $x = \\text{low} +
    u\\,(\\text{high} - \\text{low})$."""

    low: jax.Array
    high: jax.Array

    def __init__(self, low, high):
        self.low = _param(low, "Uniform.low")
        self.high = _param(high, "Uniform.high")
        _check(self.high >= self.low, "Uniform needs high >= low", (low, high))

    def ppf(self, u):
        return self.low + u * (self.high - self.low)

    def describe(self):
        return _describe(self, low=self.low, high=self.high)


class Normal(AbstractInverseCDFDistribution):
    """Normal $\\mathcal N(\\mu, \\sigma^2)$: $x = \\mu + \\sigma\\,\\Phi^{-1}(u)$
    ($\\sigma = 0$ keeps an entry fixed at $\\mu$)."""

    mean: jax.Array
    std: jax.Array

    def __init__(self, mean, std):
        self.mean = _param(mean, "Normal.mean")
        self.std = _param(std, "Normal.std")
        _check(self.std >= 0, "Normal.std must be >= 0", std)

    def ppf(self, u):
        return self.mean + self.std * jss.ndtri(u)

    def describe(self):
        return _describe(self, mean=self.mean, std=self.std)


class LogNormal(AbstractInverseCDFDistribution):
    """Log-normal: $\\log x \\sim \\mathcal N(\\mu, \\sigma^2)$, so
    $x = e^{\\mu + \\sigma\\Phi^{-1}(u)}$ (the median is $e^\\mu$). With
    `relative=True` on the parameter, `LogNormal(0.0, 0.1)` is a multiplicative
    scatter of about 10 % around the nominal value."""

    log_mean: jax.Array
    log_std: jax.Array

    def __init__(self, log_mean, log_std):
        self.log_mean = _param(log_mean, "LogNormal.log_mean")
        self.log_std = _param(log_std, "LogNormal.log_std")
        _check(self.log_std >= 0, "LogNormal.log_std must be >= 0", log_std)

    def ppf(self, u):
        return jnp.exp(self.log_mean + self.log_std * jss.ndtri(u))

    def describe(self):
        return _describe(self, log_mean=self.log_mean, log_std=self.log_std)


class TruncatedNormal(AbstractInverseCDFDistribution):
    """$\\mathcal N(\\mu, \\sigma^2)$ conditioned on $[\\text{low}, \\text{high}]$:
    $x = \\mu + \\sigma\\,\\Phi^{-1}\\big(\\Phi(a) + u\\,(\\Phi(b) - \\Phi(a))\\big)$,
    $a = (\\text{low} - \\mu)/\\sigma$, $b = (\\text{high} - \\mu)/\\sigma$ (use
    `-inf`/`inf` for a one-sided truncation); for $a > 0$ the same draw by the
    mirror image, $x = \\mu - \\sigma\\,\\Phi^{-1}\\big(\\Phi(-b) + (1 - u)
    (\\Phi(-a) - \\Phi(-b))\\big)$, which keeps its digits in the upper tail."""

    mean: jax.Array
    std: jax.Array
    low: jax.Array
    high: jax.Array

    def __init__(self, mean, std, low=-np.inf, high=np.inf):
        self.mean = _param(mean, "TruncatedNormal.mean")
        self.std = _param(std, "TruncatedNormal.std")
        # the bounds may be infinite: checked for NaN only
        self.low = jnp.asarray(np.asarray(low, dtype=np.float64))
        self.high = jnp.asarray(np.asarray(high, dtype=np.float64))
        _check(self.std > 0, "TruncatedNormal.std must be > 0", std)
        _check(
            ~np.isnan(np.asarray(self.low)) & ~np.isnan(np.asarray(self.high)),
            "TruncatedNormal.low/high must not be NaN",
            (low, high),
        )
        _check(self.high > self.low, "TruncatedNormal needs high > low", (low, high))

    def ppf(self, u):
        alpha = (self.low - self.mean) / self.std
        beta = (self.high - self.mean) / self.std
        # Above the mean, Phi(a) is close to 1 and a + u (Phi(b) - Phi(a)) loses
        # the digits that tell the draws apart (low = mean + 8 std: almost all inf):
        # there the mirror image, -Z conditioned on [-b, -a], is drawn with 1 - u,
        # from the small values Phi(-b) and Phi(-a).
        upper = alpha > 0
        lo = jnp.where(upper, -beta, alpha)
        hi = jnp.where(upper, -alpha, beta)
        v = jnp.where(upper, 1 - u, u)
        p_lo, p_hi = jss.ndtr(lo), jss.ndtr(hi)
        z = jss.ndtri(p_lo + v * (p_hi - p_lo))
        x = self.mean + self.std * jnp.where(upper, -z, z)
        return jnp.clip(x, self.low, self.high)

    def describe(self):
        return _describe(
            self, mean=self.mean, std=self.std, low=self.low, high=self.high
        )


class Custom(AbstractDistribution):
    """A user-supplied sampler `fn(key) -> value` (a value of the leaf's shape, or
    one that broadcasts to it). Random sampling only (it has no inverse CDF unless
    `ppf(u)` is given, with `u` of the leaf's shape)."""

    fn: Callable = eqx.field(static=True)
    inverse_cdf: Callable | None = eqx.field(static=True, default=None)

    def __init__(self, fn, ppf=None):
        if not callable(fn):
            raise ValueError(f"Custom.fn must be callable fn(key) -> value, got {fn!r}")
        if ppf is not None and not callable(ppf):
            raise ValueError(
                f"Custom.ppf must be callable ppf(u) -> value, got {ppf!r}"
            )
        self.fn = fn
        self.inverse_cdf = ppf

    def sample(self, key, shape):
        return jnp.broadcast_to(jnp.asarray(self.fn(key), jnp.float64), shape)

    def ppf(self, u):
        if self.inverse_cdf is None:
            raise ValueError(
                "Custom distribution without ppf has no inverse CDF, so it cannot be "
                "used with Latin hypercube sampling; use sampling='random' or pass "
                "Custom(fn, ppf=...)"
            )
        return jnp.asarray(self.inverse_cdf(u), jnp.float64)

    @property
    def supports_ppf(self) -> bool:
        return self.inverse_cdf is not None

    def describe(self):
        name = getattr(self.fn, "__qualname__", repr(self.fn))
        return {"type": "Custom", "fn": name}


def _describe(dist, **params) -> dict:
    return {"type": type(dist).__name__} | {
        k: np.asarray(v).tolist() for k, v in params.items()
    }
