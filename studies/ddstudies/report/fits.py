"""Least-squares fits of the study laws: C (1 + log(H/h))^2, a x + b, a + b log x, a + b sqrt(x) and
C1 + C2 (1 + log x)^2, each with its R^2; pairs with a non-finite value are ignored.

The figures of :mod:`ddstudies.report.plots` draw these fits (its ``FIT_MODELS``); the tables use them
directly (e.g. :func:`ddstudies.report.plots.hbhs_growth`).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["log_squared", "fit_log_squared", "fit_linear", "fit_log_squared_affine", "fit_log_linear",
           "fit_sqrt_linear", "r2_text", "MIN_FIT_POINTS"]

#: Fewest sizes of a fitted growth law that a target judges (two points fit any two-parameter law exactly).
MIN_FIT_POINTS = 3


def r2_text(r2: float, n_points: int, *, n_params: int = 2, spec: str = ".3f", label: str = "") -> str:
    """R^2 of a least-squares fit as every table, legend and report shows it.

    A law with ``n_params`` parameters passes through ``n_params`` points exactly, so its R^2 = 1 says
    nothing about the law: "exact, 2 points"; fewer points fit nothing: "no fit, 1 point". Otherwise
    ``label`` followed by R^2 in ``spec`` ("n/a" where it is not finite).
    """
    points = f"{n_points} point{'s' if n_points != 1 else ''}"
    if n_points < n_params:
        return f"no fit, {points}"
    if n_points == n_params:
        return f"exact, {points}"
    return label + (format(r2, spec) if math.isfinite(r2) else "n/a")


def _finite_pairs(x, y) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if x.shape != y.shape:
        raise ValueError(f"x and y differ in length: {x.size} != {y.size}")
    keep = np.isfinite(x) & np.isfinite(y)
    return x[keep], y[keep]


def _r_squared(y: np.ndarray, fitted: np.ndarray) -> float:
    """Coefficient of determination 1 - SS_res / SS_tot (SS_tot about the mean).

    NaN with fewer than two points or when all y are equal (SS_tot = 0). For a
    fit without intercept it can be negative (worse than the mean).
    """
    if y.size < 2:
        return math.nan
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    if ss_tot == 0.0:
        return math.nan
    ss_res = float(np.sum((y - fitted) ** 2))
    return 1.0 - ss_res / ss_tot


def log_squared(h_ratio) -> np.ndarray:
    """The model shape ``(1 + log(H/h))^2`` (natural logarithm)."""
    return (1.0 + np.log(np.asarray(h_ratio, dtype=float))) ** 2


def fit_log_squared(h_ratio, cond) -> tuple[float, float]:
    """Least-squares fit of ``cond ~ C (1 + log(H/h))^2``.

    Parameters
    ----------
    h_ratio : array_like
        H/h values (> 0).
    cond : array_like
        Condition number estimates. Pairs with a non-finite value are ignored.

    Returns
    -------
    (C, r2) : tuple of float
        ``C = sum(g * cond) / sum(g * g)`` with ``g = (1 + log(H/h))^2``, and
        R^2 (see :func:`_r_squared`; NaN for fewer than two points). C is NaN
        when no usable point is left.
    """
    x, y = _finite_pairs(h_ratio, cond)
    if np.any(x <= 0):
        raise ValueError("H/h must be positive")
    if x.size == 0:
        return math.nan, math.nan
    g = log_squared(x)
    denom = float(np.dot(g, g))
    if denom == 0.0:
        return math.nan, math.nan
    c = float(np.dot(g, y)) / denom
    return c, _r_squared(y, c * g)


def fit_linear(x, y) -> tuple[float, float, float]:
    """Least-squares line ``y ~ slope * x + intercept``.

    Returns
    -------
    (slope, intercept, r2) : tuple of float
        NaN slope/intercept with fewer than two distinct x values; R^2 as in
        :func:`fit_log_squared`.
    """
    x, y = _finite_pairs(x, y)
    if x.size < 2 or np.all(x == x[0]):
        return math.nan, math.nan, math.nan
    xm, ym = x.mean(), y.mean()
    slope = float(np.dot(x - xm, y - ym) / np.dot(x - xm, x - xm))
    intercept = float(ym - slope * xm)
    return slope, intercept, _r_squared(y, slope * x + intercept)


def fit_log_squared_affine(h_ratio, y) -> tuple[float, float, float]:
    """Least-squares fit of ``y ~ C1 + C2 (1 + log(x))^2`` (natural logarithm).

    The FETI-FETI bound of Theorem 4.3.x grows like (1 + log(H_s/h))^2 for a
    fixed H_b/H_s; unlike :func:`fit_log_squared` this fit has an intercept.

    Parameters
    ----------
    h_ratio : array_like
        x values (> 0), e.g. H_s/h.
    y : array_like
        Values; pairs with a non-finite value are ignored.

    Returns
    -------
    (C1, C2, r2) : tuple of float
        NaN with fewer than two distinct x values; R^2 as in :func:`fit_linear`.
    """
    x, y = _finite_pairs(h_ratio, y)
    if np.any(x <= 0):
        raise ValueError("x must be positive")
    slope, intercept, r2 = fit_linear(log_squared(x), y)
    return intercept, slope, r2


def fit_log_linear(x, y) -> tuple[float, float, float]:
    """Least-squares fit of ``y ~ a + b log(x)`` (natural logarithm).

    Returns
    -------
    (a, b, r2) : tuple of float
        NaN with fewer than two distinct x values.
    """
    x, y = _finite_pairs(x, y)
    if np.any(x <= 0):
        raise ValueError("x must be positive")
    slope, intercept, r2 = fit_linear(np.log(x), y)
    return intercept, slope, r2


def fit_sqrt_linear(x, y) -> tuple[float, float, float]:
    """Least-squares fit of ``y ~ a + b sqrt(x)``.

    CG iterations for a condition number growing linearly in x grow like
    sqrt(x) (the FETI-FETI iterations against H_b/H_s).

    Returns
    -------
    (a, b, r2) : tuple of float
        NaN with fewer than two distinct x values.
    """
    x, y = _finite_pairs(x, y)
    if np.any(x < 0):
        raise ValueError("x must be non-negative")
    slope, intercept, r2 = fit_linear(np.sqrt(x), y)
    return intercept, slope, r2


def _model(fit):
    """``fit(x, y) -> (*params, r2)`` as ``(x, y) -> (params, r2)``, the form of the figures' FIT_MODELS."""
    def run(x, y):
        *params, r2 = fit(x, y)
        return tuple(params), r2
    return run


_fit_linear_model = _model(fit_linear)                  # (slope, intercept)
_fit_log_linear_model = _model(fit_log_linear)          # (a, b) of a + b log x
_fit_sqrt_linear_model = _model(fit_sqrt_linear)        # (a, b) of a + b sqrt(x)
_fit_log_squared_affine_model = _model(fit_log_squared_affine)      # (C1, C2)
