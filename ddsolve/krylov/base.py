"""Base class of the Krylov solvers: everything but the recurrence.

As in NGSolve's ``krylovspace.py``, :class:`KrylovSolver` does the argument
checks, the operator conversion, the history, the callback, the stopping test
and its reasons, the recomputed ("true") residual and the convergence policy
of :mod:`ddsolve.krylov.convergence`, and the restart policy
(:meth:`KrylovSolver.restarted`). A subclass writes only its recurrence in
:meth:`KrylovSolver.iterate` (:class:`~ddsolve.krylov.pcg.PCG`, Figure 1.2 of
Lee 2009; :class:`~ddsolve.krylov.pcr.PCR`, Section 1.3.2 / Figure 1.3).

Scale safety: the iteration runs on the system scaled by a power of two
``2^k`` (exact in floating point, so the iterates are the same numbers) chosen
so that the initial residual has entries of order one whenever it is outside
``[2^-64, 2^64]``; norms are computed with :func:`~ddsolve.krylov.convergence.norm2`.
Multiplying ``b`` by any factor in 1e-300..1e300 therefore neither
underflows nor overflows the inner products.
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import aslinearoperator

from ..errors import InputError, brief
from .convergence import (
    RESTART_FACTOR,
    TRUE_RESIDUAL_FACTOR,
    attained_residual,
    norm2,
    not_attained_reason,
)
from .result import KrylovResult

__all__ = ["BREAKDOWN", "CONVERGED", "MAXITER", "KrylovSolver"]

logger = logging.getLogger(__name__)

Matvec = Callable[[np.ndarray], np.ndarray]

#: Outcomes of :meth:`KrylovSolver.iterate`.
CONVERGED, MAXITER, BREAKDOWN = "converged", "maxiter", "breakdown"
#: A breakdown below this residual ratio ||r|| / ||r0|| is rounding (:meth:`KrylovSolver.breakdown`).
ROUNDING_LEVEL = 1e-10
#: An initial guess with ||r_0||_2 <= X0_ROUNDING_FACTOR eps (||b||_2 + ||A x_0||_2) solves the system to
#: rounding (a normwise backward error of that order; ||A x_0|| stands for ||A|| ||x_0||, which bounds it):
#: no iteration can lower such a residual, so it is accepted before the first step instead of ending
#: "tolerance not attained" against a threshold rtol ||r_0|| below rounding.
X0_ROUNDING_FACTOR = 64.0

# The iteration runs unscaled while max |r_0| lies in [2^-_SCALE_FREE, 2^_SCALE_FREE].
_SCALE_FREE = 64


def as_matvec(op: Any, n: int | None, name: str) -> tuple[Matvec, int]:
    """Return ``(v -> op @ v, n)`` for a square operator, checking its shape.

    ``op`` may be a dense ndarray, a scipy sparse matrix/array, a
    ``LinearOperator`` or any object with ``.matvec`` and ``.shape``. Dense and
    sparse matrices are applied with ``.dot`` directly (no LinearOperator
    overhead).
    """
    if isinstance(op, np.matrix):
        op = np.asarray(op)
    if isinstance(op, np.ndarray) or sp.issparse(op):
        shape = op.shape
        if len(shape) != 2:
            raise InputError(name, f"must be a 2-D operator, got shape {shape}")
        func: Matvec = op.dot
    else:
        try:
            lin = aslinearoperator(op)
        except (TypeError, ValueError) as exc:
            raise InputError(
                name,
                f"cannot be used as a linear operator ({type(op).__name__}): "
                "need an ndarray, sparse matrix, LinearOperator or an object "
                "with .matvec and .shape",
            ) from exc
        shape = lin.shape
        func = lin.matvec
    if shape[0] != shape[1]:
        raise InputError(name, f"must be square, got shape {tuple(shape)}")
    dtype = getattr(op, "dtype", None)
    if dtype is not None and np.issubdtype(np.dtype(dtype), np.complexfloating):
        raise InputError(name, "complex operators are not supported (real symmetric operators only)")
    if n is not None and shape[0] != n:
        raise InputError(name, f"has shape {tuple(shape)}, expected ({n}, {n})")
    return func, int(shape[0])


def apply(op: Matvec, v: np.ndarray, name: str = "A") -> np.ndarray:
    """Apply a matvec and return a writable contiguous float64 1-D array (``name``: the operator, for errors)."""
    out = np.asarray(op(v))
    if np.iscomplexobj(out):
        # real values in a complex type, up to the rounding of e.g. an FFT preconditioner, pass as real
        imag, real = np.abs(out.imag), np.abs(out.real)
        if not imag.max(initial=0.0) <= 64.0 * np.finfo(float).eps * real.max(initial=0.0):
            raise InputError(name, "the operator returned complex values: complex operators are not supported")
        out = out.real
    if out.ndim != 1:
        out = out.reshape(-1)
    if out.dtype != np.float64 or not out.flags.writeable or not out.flags.c_contiguous:
        out = np.array(out, dtype=np.float64)
    return out


def _vector(value: Any, name: str, n: int) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise InputError(name, f"must be an array of numbers, got {brief(value)}")
    if np.iscomplexobj(arr):
        what = "right-hand sides" if name == "b" else "initial guesses"
        raise InputError(name, f"complex {what} are not supported")
    if not (arr.ndim <= 1 or (arr.ndim == 2 and 1 in arr.shape)):
        raise InputError(name, f"has shape {arr.shape}, expected ({n},), ({n}, 1) or (1, {n})")
    out = np.array(arr, dtype=np.float64).reshape(-1)
    if out.size != n:
        extra = f" (operator is {n} x {n})" if name == "b" else ""
        raise InputError(name, f"has {out.size} entries, expected {n}{extra}")
    return out


class KrylovSolver:
    """A (projected, preconditioned) Krylov solve of ``A x = b``: bookkeeping and policy.

    Parameters
    ----------
    A : ndarray, sparse matrix, LinearOperator or object with ``.matvec``/``.shape``
        The operator, shape (n, n).
    b : array_like, shape (n,)
        Right-hand side.
    x0 : array_like, shape (n,), optional
        Initial guess (zero by default; then no operator application is spent
        on the initial residual).
    rtol, atol : float
        Stop when ``||r_k|| <= max(rtol * ||r_0||, atol)`` in the stopping
        norm (``r`` the projected residual when ``P`` is given). At least one
        must be > 0.
    maxiter : int, optional
        Maximum number of iterations, ``10 * n`` by default.
    M : operator, shape (n, n), optional
        SPD *inverse* preconditioner, ``z = M r`` (as in scipy); identity by default.
    P : operator, shape (n, n), optional
        Orthogonal projection (symmetric, ``P^2 = P``); identity by default.
    callback : callable, optional
        ``callback(xk)`` after each iteration with a read-only view of the
        current iterate, shape (n,).

    Notes
    -----
    A subclass implements :meth:`iterate` with :meth:`op`,
    :meth:`precondition`, :meth:`advance` and :meth:`breakdown`, and may
    override :meth:`initial_norm`, :meth:`true_residual`, :meth:`label` and
    :meth:`result_fields`. :meth:`solve` returns the :class:`KrylovResult`:
    ``converged`` only if the recursive residual met the threshold, the
    residual recomputed from the returned ``x`` meets it within
    :data:`~ddsolve.krylov.convergence.TRUE_RESIDUAL_FACTOR`, and ``x`` and the
    recomputed residual are finite.

    Raises
    ------
    InputError
        (a ``ValueError``) for invalid arguments: shape mismatch, both
        ``rtol`` and ``atol`` <= 0, ``maxiter < 1``, an unusable operator.
    """

    #: name used in log messages
    name: ClassVar[str] = "krylov"

    def __init__(self, A: Any, b: Any, x0: Any = None, *, rtol: float = 1e-6, atol: float = 0.0,
                 maxiter: int | None = None, M: Any = None, P: Any = None,
                 callback: Callable[[np.ndarray], Any] | None = None) -> None:
        if A is None:
            raise InputError("A", "operator is required")
        self.A, n = as_matvec(A, None, "A")
        if n == 0:
            raise InputError("A", "operator has size 0")
        self.n = n
        self.M = None if M is None else as_matvec(M, n, "M")[0]
        self.P = None if P is None else as_matvec(P, n, "P")[0]
        self.b = _vector(b, "b", n)
        self.x0_given = x0 is not None
        self.x = np.zeros(n) if x0 is None else _vector(x0, "x0", n)
        for label, value in (("rtol", rtol), ("atol", atol)):
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise InputError(label, f"must be a real number >= 0, got {value!r}")
            if not math.isfinite(float(value)) or float(value) < 0.0:
                raise InputError(label, f"must be a finite number >= 0, got {value!r}")
        if float(rtol) <= 0.0 and float(atol) <= 0.0:
            raise InputError("rtol", "rtol and atol are both <= 0: at least one must be positive")
        self.rtol, self.atol = float(rtol), float(atol)
        if maxiter is None:
            self.maxiter = 10 * n
        else:
            if isinstance(maxiter, bool) or not isinstance(maxiter, (int, np.integer)):
                raise InputError("maxiter", f"must be an integer >= 1 or None, got {maxiter!r}")
            self.maxiter = int(maxiter)
            if self.maxiter < 1:
                raise InputError("maxiter", f"must be >= 1, got {self.maxiter}")
        if callback is not None and not callable(callback):
            raise InputError("callback", f"must be callable or None, got {brief(callback)}")
        self.callback = callback
        # iteration state (set by solve)
        self.r = np.zeros(0)
        self.scale = 1.0
        self.rnorm0 = 0.0
        self.threshold = 0.0
        self.x0_floor: float | None = None      # set with x0: see X0_ROUNDING_FACTOR
        self.matvecs = 0
        self.iterations = 0
        self.residuals: list[float] = []
        self.reason = ""
        self.outcome = ""
        self.debug = logger.isEnabledFor(logging.DEBUG)
        self.tmp = np.empty(0)
        self._x_view: np.ndarray | None = None

    # ------------------------------------------------------------ recurrence
    def iterate(self) -> str:
        """Run the recurrence from ``self.x``, ``self.r``; return CONVERGED, MAXITER or BREAKDOWN."""
        raise NotImplementedError

    # ------------------------------------------------------- subclass tools
    def op(self, v: np.ndarray) -> np.ndarray:
        """``P A v`` (counts one operator application)."""
        self.matvecs += 1
        w = apply(self.A, v)
        return w if self.P is None else apply(self.P, w, "P")

    def precondition(self, v: np.ndarray) -> np.ndarray:
        """``P M v`` (a fresh array; ``P v`` without ``M``)."""
        z = v.copy() if self.M is None else apply(self.M, v, "M")
        return z if self.P is None else apply(self.P, z, "P")

    def advance(self, rnorm: float) -> str | None:
        """Record one finished iteration with residual norm ``rnorm``; call back; stop test.

        Returns None to continue, or CONVERGED / MAXITER / BREAKDOWN with
        ``self.reason`` set.
        """
        self.iterations += 1
        k = self.iterations
        self.residuals.append(rnorm)
        if self.debug:
            logger.debug("%s it %d: ||r||/||r0|| = %.3e", self.name, k, rnorm / self.rnorm0)
        if self.callback is not None:
            self.callback(self._x_view if self.scale == 1.0 else self._readonly(self.x / self.scale))
        if not math.isfinite(rnorm):
            self.reason = f"breakdown: non-finite residual at iteration {k}"
            return BREAKDOWN
        if rnorm <= self.threshold:
            self.reason = self.label(f"converged: ||r||/||r0|| = {rnorm / self.rnorm0:.1e} "
                                     f"<= {self.threshold / self.rnorm0:.1e}")
            return CONVERGED
        if k >= self.maxiter:
            self.reason = self.label(f"maxiter {self.maxiter} reached: ||r||/||r0|| = "
                                     f"{rnorm / self.rnorm0:.1e} > {self.threshold / self.rnorm0:.1e}")
            return MAXITER
        return None

    def breakdown(self, reason: str) -> str:
        """Set ``reason`` (which starts with ``breakdown:``) and return BREAKDOWN.

        A breakdown after the residual fell to the rounding level (||r|| <= 1e-10 ||r0||) is noted as
        such: a tolerance below the attainable accuracy, not an indefinite operator (a review:
        ``solve_feti(rtol=1e-20)`` read "operator not positive definite")."""
        rnorm0 = getattr(self, "rnorm0", 0.0)
        if self.residuals and rnorm0 > 0 and self.residuals[-1] <= ROUNDING_LEVEL * rnorm0:
            reason = (f"{reason}; the residual had reached {self.residuals[-1] / rnorm0:.1e} of ||r0||: "
                      f"rounding (a tolerance below the attainable accuracy), not the operator")
        self.reason = reason
        return BREAKDOWN

    # ------------------------------------------------------------ reductions
    # The only places where the recurrence reduces a vector to a number. A distributed
    # solver (:mod:`ddsolve.parallel.krylov`) overrides them with global reductions;
    # the recurrence itself is unchanged, so serial and parallel iterates agree.
    def inner(self, a: np.ndarray, b: np.ndarray) -> float:
        """Inner product ``<a, b>``."""
        return float(np.dot(a, b))

    def inners(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> list[float]:
        """``[<a, b> for (a, b) in pairs]``: several inner products that a recurrence needs at the
        same point, so that a distributed solver sums them in one reduction (the values are those
        of :meth:`inner`; an overflow is a non-finite value for the recurrence to handle, quietly,
        as in :func:`~ddsolve.krylov.convergence.norm2`)."""
        with np.errstate(over="ignore", invalid="ignore"):
            return [self.inner(a, b) for a, b in pairs]

    def l2norm(self, v: np.ndarray) -> float:
        """Euclidean norm ``||v||_2`` (:func:`~ddsolve.krylov.convergence.norm2`)."""
        return norm2(v)

    def absmax(self, v: np.ndarray) -> float:
        """``max |v_i|`` (NaN if ``v`` holds a NaN)."""
        return float(np.max(np.abs(v)))

    def label(self, reason: str) -> str:
        """Hook: name the stopping norm in a reason (identity for ``||.||_2``)."""
        return reason

    def initial_norm(self, r: np.ndarray) -> float:
        """Norm of the initial residual in the stopping norm (``||r||_2``)."""
        return self.l2norm(r)

    def initial_failure(self, rnorm0: float) -> tuple[str, float]:
        """Reason and recorded norm when :meth:`initial_norm` is not finite."""
        return "breakdown: non-finite initial residual (NaN/inf in A, b, x0 or P)", rnorm0

    def true_residual(self, x: np.ndarray) -> float:
        """``||P (b - A x)||_2`` recomputed from ``x`` (one operator application)."""
        r = self.b - apply(self.A, x)
        if self.P is not None:
            r = apply(self.P, r, "P")
        return self.l2norm(r)

    def result_fields(self) -> dict[str, Any]:
        """Hook: extra :class:`KrylovResult` fields (e.g. Lanczos estimates)."""
        return {}

    @staticmethod
    def _readonly(x: np.ndarray) -> np.ndarray:
        view = x.view()
        view.flags.writeable = False
        return view

    # ----------------------------------------------------------------- solve
    def _initial_residual(self) -> np.ndarray:
        """``r_0 = P (b - A x_0)`` (no operator application when ``x0`` is None)."""
        # a zero x0 is no start (r_0 = P b exactly, no subtraction to round): iterate as for x0 = None. With a
        # projection, b large outside range(P) made the floor below accept x0 = 0, 100% wrong, as "solved to
        # rounding" (a review). l2norm is a global reduction under MPI: every rank decides alike.
        if self.x0_given and not self.l2norm(self.x) == 0.0:      # a NaN x0 is a start: it fails at once
            Ax0 = apply(self.A, self.x)
            r = self.b - Ax0
            self.matvecs += 1
            # the rounding of b - A x0 in every component; a non-diagonal P carries it into range(P)
            self.x0_floor = X0_ROUNDING_FACTOR * np.finfo(float).eps * (self.l2norm(self.b) + self.l2norm(Ax0))
        else:
            r = self.b.copy()
        if self.P is not None:
            r = apply(self.P, r, "P")
        return r

    def _rescale(self, r: np.ndarray) -> None:
        """Scale the system by a power of two so that max |r_0| is of order one (exact)."""
        amax = self.absmax(r)
        if not (0.0 < amax < math.inf):
            return
        exponent = math.frexp(amax)[1]
        if -_SCALE_FREE <= exponent <= _SCALE_FREE:
            return
        self.scale = math.ldexp(1.0, max(-1000, min(1000, -exponent)))
        r *= self.scale
        self.x *= self.scale
        self.b = self.b * self.scale
        self.atol *= self.scale

    def _result(self, t0: float, converged: bool, true_res: float | None, attained: bool | None,
                **fields: Any) -> KrylovResult:
        unscale = 1.0 / self.scale
        x = self.x if self.scale == 1.0 else self.x * unscale
        residuals = np.asarray(self.residuals, dtype=float)
        if self.scale != 1.0:
            residuals = residuals * unscale
            true_res = None if true_res is None else true_res * unscale
        seconds = time.perf_counter() - t0
        logger.debug("%s: %s (%d iterations, %.3g s)", self.name, self.reason, self.iterations, seconds)
        return KrylovResult(x=x, converged=converged, reason=self.reason, iterations=self.iterations,
                            residuals=residuals, matvecs=self.matvecs, seconds=seconds,
                            true_residual=true_res, attained=attained, **fields)

    def solve(self) -> KrylovResult:
        """Run the iteration and apply the convergence policy; see the class docstring."""
        t0 = time.perf_counter()
        if self.P is None and self.absmax(self.b) == 0.0:      # b = 0 (no NaN)
            self.x = np.zeros(self.n)
            self.residuals = [0.0]
            self.reason = "converged: zero right-hand side b = 0, so x = 0"
            self.outcome = CONVERGED
            return self._result(t0, True, 0.0, True)
        r = self._initial_residual()
        self._rescale(r)
        self.r = r
        rnorm0 = self.initial_norm(r)
        if not math.isfinite(rnorm0):
            self.reason, recorded = self.initial_failure(rnorm0)
            self.residuals = [recorded]
            self.outcome = BREAKDOWN
            return self._result(t0, False, None, None)
        self.rnorm0 = rnorm0
        self.threshold = threshold = max(self.rtol * rnorm0, self.atol)
        self.residuals = [rnorm0]
        floor = self.x0_floor
        r2 = self.l2norm(r) if floor is not None and rnorm0 > threshold else math.inf    # the stopping norm may differ
        if r2 <= (floor or 0.0) * self.scale:
            self.reason = (f"converged: x0 solves the system to rounding (||r0|| = {r2 / self.scale:.1e}"
                           f" <= {X0_ROUNDING_FACTOR:g} eps (||b|| + ||A x0||) = {floor:.1e})")
            self.outcome = CONVERGED
            return self._result(t0, True, rnorm0, True)
        if rnorm0 == 0.0 or rnorm0 <= threshold:
            rule = (f"atol = {self.atol / self.scale:.1e}" if self.atol >= self.rtol * rnorm0 else
                    f"rtol ||r0|| = {self.rtol:g} ||r0|| (rtol >= 1 stops before the first step)")
            self.reason = ("converged: ||r0|| = 0" if rnorm0 == 0.0 else
                           f"converged: ||r0|| = {rnorm0 / self.scale:.1e} <= {rule}")
            self.outcome = CONVERGED
            return self._result(t0, True, rnorm0, True)

        self.tmp = np.empty_like(self.x)
        self._x_view = self._readonly(self.x) if self.callback is not None and self.scale == 1.0 else None
        # an overflow or 0 * inf is a non-finite value that the recurrence reports as its breakdown, and
        # the recomputed residual as not attained (never converged), quietly: no numpy RuntimeWarning
        with np.errstate(over="ignore", invalid="ignore"):
            self.outcome = outcome = self.iterate()
            fields = self.result_fields()
            true_res = self.true_residual(self.x)
        self.matvecs += 1
        ok = attained_residual(true_res, threshold)
        converged = outcome == CONVERGED
        if converged and not (math.isfinite(true_res) and bool(np.all(np.isfinite(self.x)))):
            converged = False
            self.reason = f"non-finite iterate or recomputed residual ({true_res:.1e}) although {self.reason}"
        elif converged and not ok:
            converged = False
            rec = self.residuals[-1] / rnorm0
            self.reason = not_attained_reason(true_res / rnorm0, rec, TRUE_RESIDUAL_FACTOR,
                                              threshold / rnorm0)
        return self._result(t0, converged, true_res, ok, **fields)

    # --------------------------------------------------------------- restart
    @classmethod
    def restarted(cls, A: Any, b: Any, x0: Any = None, *, rtol: float, atol: float = 0.0,
                  maxiter: int, restart: int, factor: float = RESTART_FACTOR,
                  **options: Any) -> KrylovResult:
        """Solve in cycles of at most ``restart`` iterations, each restarted from the last iterate.

        The threshold ``max(rtol ||r_0||, atol)`` is fixed by the first cycle;
        the later cycles stop at it (``rtol=0, atol=threshold``), starting with
        the true residual of their initial iterate. A cycle ends the solve when
        it converged and its recomputed residual is within ``factor`` of the
        threshold, when it broke down, made no iteration, or the budget of
        ``maxiter`` iterations is spent.

        Parameters
        ----------
        A, b, x0, rtol, atol :
            As for the class.
        maxiter : int
            Iterations of all cycles together.
        restart : int
            Iterations per cycle (at least 1).
        factor : float
            Acceptance factor of the recomputed residual (:data:`RESTART_FACTOR`).
        **options
            Further keyword arguments of the subclass (``M``, ``P``, ``norm``...).

        Returns
        -------
        KrylovResult
            The single cycle's result if there was one; otherwise iterations,
            matvecs, seconds and the residual histories of all cycles, the last
            cycle's ``x`` and ``true_residual``, ``restarts`` = number of cycles
            - 1, ``converged`` when the last cycle converged with a recomputed
            residual within ``factor`` of the threshold (then ``attained``), and
            Lanczos estimates where the cycles have them (``cond=True``): the
            smallest ``lambda_min`` and the largest ``lambda_max`` of the cycles.
        """
        cycles: list[KrylovResult] = []
        x = x0
        threshold: float | None = None
        while True:
            used = sum(c.iterations for c in cycles)
            budget = min(max(int(restart), 1), maxiter - used)
            if threshold is None:
                solver = cls(A, b, x, rtol=rtol, atol=atol, maxiter=max(budget, 1), **options)
                kr = solver.solve()
                threshold = max(rtol * float(kr.residuals[0]), atol)
            else:
                solver = cls(A, b, x, rtol=0.0, atol=threshold, maxiter=budget, **options)
                kr = solver.solve()
            cycles.append(kr)
            true_ok = kr.true_residual is not None and kr.true_residual <= factor * threshold
            if (kr.converged and true_ok) or solver.outcome == BREAKDOWN:
                break
            if kr.iterations == 0 or maxiter - used - kr.iterations <= 0:
                break
            logger.debug("%s: restarting after %d iterations (%s, true residual %.2e, target %.2e)",
                         cls.name, kr.iterations, kr.reason, kr.true_residual, threshold)
            x = kr.x
        if len(cycles) == 1:
            return cycles[0]
        last = cycles[-1]
        ok = last.true_residual is not None and last.true_residual <= factor * threshold
        # the cycles' own reasons are relative to their own r_0 and budget (a review read "maxiter 100
        # reached: ... > 2.9e-14" for --maxiter 1000 and rtol 1e-6): restate the last one for the whole solve
        rnorm0, rnorm = float(cycles[0].residuals[0]), float(last.residuals[-1])
        done = f"after {len(cycles) - 1} restart(s) of at most {max(int(restart), 1)} iterations"
        if solver.outcome == CONVERGED and not ok:
            # the last cycle stopped on a rule that is not the tolerance (its x0 solves its system to rounding)
            reason = (f"tolerance not attained: recomputed residual {last.true_residual:.1e} > {factor:g} x the "
                      f"target {threshold:.1e} (rtol below the attainable accuracy) {done}")
        elif solver.outcome in (CONVERGED, MAXITER) and rnorm0 > 0 and last.reason.startswith(("converged", "maxiter")):
            head = "converged" if solver.outcome == CONVERGED else f"maxiter {maxiter} reached"
            relation = "<=" if solver.outcome == CONVERGED else ">"
            reason = solver.label(f"{head}: ||r||/||r0|| = {rnorm / rnorm0:.1e} {relation} {threshold / rnorm0:.1e} "
                                  f"{done}")
        else:
            reason = f"{last.reason} {done}"
        return KrylovResult(
            x=last.x, converged=last.converged and ok,
            reason=reason,
            iterations=sum(c.iterations for c in cycles),
            residuals=np.concatenate([cycles[0].residuals] + [c.residuals[1:] for c in cycles[1:]]),
            matvecs=sum(c.matvecs for c in cycles), seconds=sum(c.seconds for c in cycles),
            true_residual=last.true_residual, attained=ok, restarts=len(cycles) - 1,
            **_merged_estimates(cycles))


def _merged_estimates(cycles: list[KrylovResult]) -> dict[str, float]:
    """The Lanczos estimates of restarted cycles (those that have them): the smallest lambda_min and the
    largest lambda_max. Each cycle's Ritz values lie inside the spectrum of the same operator, so these
    are the best inner estimates of its ends (a review: ``restarted(..., cond=True)`` dropped them after
    one restart)."""
    lows = [c.lambda_min for c in cycles if c.lambda_min is not None]
    highs = [c.lambda_max for c in cycles if c.lambda_max is not None]
    if not lows or not highs:
        return {}
    lam_min, lam_max = min(lows), max(highs)
    return {"lambda_min": lam_min, "lambda_max": lam_max, "cond": lam_max / lam_min if lam_min > 0.0 else math.inf}
