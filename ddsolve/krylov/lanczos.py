"""Extreme eigenvalue estimates from the PCG coefficients (Lanczos connection).

PCG applied to ``A x = b`` with the (inverse) preconditioner ``M`` implicitly
runs the Lanczos process on the preconditioned operator ``M A``; the step
lengths ``alpha_k`` and the direction coefficients ``beta_k`` of Figure 1.2 of
Lee (2009) determine the Lanczos tridiagonal matrix ``T_m``, whose extreme
eigenvalues (Ritz values) approximate those of ``M A`` from inside the
spectrum. Their ratio is the usual estimate of the condition number reported
by FETI / BDDC codes.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.linalg import eigvalsh_tridiagonal

from ..errors import InputError

__all__ = ["lanczos_tridiagonal", "lanczos_extreme_eigenvalues"]


def lanczos_tridiagonal(
    alphas: Sequence[float] | np.ndarray, betas: Sequence[float] | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal and off-diagonal of the Lanczos matrix ``T_m`` built from PCG.

    Parameters
    ----------
    alphas : array_like, shape (m,)
        PCG step lengths ``alpha_0 .. alpha_{m-1}`` (all nonzero).
    betas : array_like, shape (m - 1,) or longer
        PCG direction coefficients ``beta_0 .. beta_{m-2}`` (``beta_k`` is the
        one computed after ``alpha_k``); entries beyond ``m - 1`` are ignored.

    Returns
    -------
    diag : ndarray, shape (m,)
        ``T[0, 0] = 1 / alpha_0`` and
        ``T[k, k] = 1 / alpha_k + beta_{k-1} / alpha_{k-1}`` for ``k >= 1``.
    offdiag : ndarray, shape (m - 1,)
        ``T[k, k + 1] = T[k + 1, k] = sqrt(beta_k) / alpha_k``.

    Raises
    ------
    InputError
        (a ``ValueError``) if ``alphas`` is empty, an ``alpha`` is zero or
        non-finite, a ``beta`` is negative or non-finite, or too few ``betas``
        are given.
    """
    a = np.asarray(alphas, dtype=float).ravel()
    b = np.asarray(betas, dtype=float).ravel()
    m = a.size
    if m == 0:
        raise InputError("alphas", "need at least one PCG step length")
    if b.size < m - 1:
        raise InputError("betas", f"need at least {m - 1} values for {m} alphas, got {b.size}")
    b = b[: m - 1]
    if not np.all(np.isfinite(a)) or np.any(a == 0.0):
        raise InputError("alphas", "must be finite and nonzero")
    if not np.all(np.isfinite(b)) or np.any(b < 0.0):
        raise InputError("betas", "must be finite and >= 0")
    inv_a = 1.0 / a
    diag = inv_a.copy()
    diag[1:] += b * inv_a[:-1]
    offdiag = np.sqrt(b) * inv_a[:-1]
    return diag, offdiag


def lanczos_extreme_eigenvalues(
    alphas: Sequence[float] | np.ndarray, betas: Sequence[float] | np.ndarray
) -> tuple[float, float]:
    """Smallest and largest eigenvalue of the PCG Lanczos matrix ``T_m``.

    Parameters
    ----------
    alphas : array_like, shape (m,)
        PCG step lengths ``alpha_0 .. alpha_{m-1}`` (Figure 1.2 of the thesis).
    betas : array_like, shape (m - 1,) or longer
        PCG coefficients ``beta_0 .. beta_{m-2}``; extra entries are ignored.

    Returns
    -------
    lambda_min, lambda_max : float
        Extreme eigenvalues of ``T_m`` (see :func:`lanczos_tridiagonal`),
        computed with :func:`scipy.linalg.eigvalsh_tridiagonal`. They
        approximate the extreme eigenvalues of the preconditioned operator
        ``M A`` from inside its spectrum and converge quickly when those are
        well separated.
    """
    diag, offdiag = lanczos_tridiagonal(alphas, betas)
    if diag.size == 1:
        value = float(diag[0])
        return value, value
    eig = eigvalsh_tridiagonal(diag, offdiag)
    lam_min, lam_max = float(eig[0]), float(eig[-1])
    if not (math.isfinite(lam_min) and math.isfinite(lam_max)):
        raise InputError("alphas", "Lanczos matrix has non-finite eigenvalues")
    return lam_min, lam_max
