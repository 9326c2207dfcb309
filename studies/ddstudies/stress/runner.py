"""Stress study, the runner: :func:`run_case` solves one :class:`~ddstudies.stress.catalogue.StressCase`.

It returns a flat, JSON-serialisable record (iterations, condition estimate,
true and recursive relative residual, error against the direct solver, ...)
and never raises: an exception becomes ``status = "crash"``, an expected
:class:`~ddsolve.errors.InputError` ``status = "input_error"``, a case that
exceeds its wall-clock limit ``status = "timeout"``.
"""
from __future__ import annotations

import contextlib
import logging
import math
import signal
import threading
import time
import traceback
from dataclasses import asdict
from typing import Any, Iterator

import numpy as np

from ddsolve.errors import InputError

from .catalogue import StressCase, contact_load

log = logging.getLogger(__name__)

__all__ = ["run_case"]


class _Timeout(Exception):
    """Raised inside a case that exceeds its wall-clock limit."""


@contextlib.contextmanager
def _deadline(seconds: float | None) -> Iterator[None]:
    """Raise :class:`_Timeout` after ``seconds`` (SIGALRM; a no-op off the main thread or on Windows)."""
    usable = (seconds is not None and seconds > 0 and hasattr(signal, "SIGALRM")
              and threading.current_thread() is threading.main_thread())
    if not usable:
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        raise _Timeout(f"no result after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, float(seconds))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


def _finite(value: Any) -> bool:
    if value is None:
        return True
    arr = np.asarray(value, dtype=float)
    return bool(np.all(np.isfinite(arr)))


def _clean(value: Any) -> Any:
    """JSON-safe scalar: numpy -> Python, non-finite floats -> None."""
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(float(value)) else None
    return value


def run_case(case: StressCase, *, timeout: float | None = None) -> dict[str, Any]:
    """Solve one case; never raises.

    Parameters
    ----------
    case : StressCase
    timeout : float, optional
        Wall-clock limit in seconds (main thread only); exceeding it gives
        ``status = "timeout"``.

    Returns
    -------
    dict
        Flat JSON-serialisable record: the case fields, ``status`` ("ok",
        "input_error", "crash", "timeout"), ``error`` (message of an
        exception), ``converged``, ``reason``, ``iterations``, ``cond``,
        ``rtol``, ``true_rel`` and ``rec_rel`` (true and recursive residual
        relative to ||r_0||), ``error_vs_direct``, ``nonfinite`` (names of
        quantities that came back NaN/inf), ``restarts``, ``seconds``, and for
        contact cases ``lambda_error``, ``force_error``, ``n_active``,
        ``n_active_direct``, ``n_contact``, ``kkt``, ``smalbe_gradient``.
    """
    from ddsolve.spec import ProblemSpec

    record: dict[str, Any] = {**asdict(case), "spec": dict(case.spec), "status": "ok", "error": "",
                              "converged": None, "reason": "", "iterations": None, "cond": None,
                              "rtol": None, "true_rel": None, "rec_rel": None, "error_vs_direct": None,
                              "nonfinite": [], "restarts": 0, "seconds": 0.0}
    t0 = time.perf_counter()
    try:
        with _deadline(timeout):
            spec = ProblemSpec.from_mapping(case.spec)
            record["rtol"] = float(spec.rtol)
            if case.runner == "contact":
                _run_contact(case, spec, record)
            else:
                _run_api(spec, record)
    except InputError as exc:
        record["status"], record["error"] = "input_error", str(exc)
    except _Timeout as exc:
        record["status"], record["error"] = "timeout", str(exc)
    except Exception as exc:  # noqa: BLE001 - a crash is a result here
        record["status"] = "crash"
        record["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0] if str(exc) else type(exc).__name__
        log.error("stress case %s crashed:\n%s", case.name, traceback.format_exc())
    record["seconds"] = time.perf_counter() - t0
    log.info("stress case %s: %s %s", case.name, record["status"], record["reason"] or record["error"])
    return {key: ([_clean(v) for v in val] if isinstance(val, list) else _clean(val))
            for key, val in record.items()}


def _run_api(spec: Any, record: dict[str, Any]) -> None:
    from ddsolve.api import solve

    res = solve(spec)
    r = np.asarray(res.residuals, dtype=float)
    checks = {"u": res.u, "residuals": r, "cond": res.cond, "true_residual": res.true_residual,
              "error_vs_direct": res.error_vs_direct}
    record["nonfinite"] = [k for k, v in checks.items() if not _finite(v)]
    r0 = float(r[0]) if r.size else 0.0
    # PCR restarts of the hybrid method: a field of the result (0 where a method has none)
    restarts = int(res.to_dict().get("restarts", 0) or 0)
    record.update(converged=bool(res.converged), reason=res.reason, iterations=int(res.iterations),
                  cond=res.cond, error_vs_direct=res.error_vs_direct, restarts=restarts)
    if r0 > 0:
        record["rec_rel"] = float(r[-1]) / r0
        if res.true_residual is not None:
            record["true_rel"] = float(res.true_residual) / r0


def _run_contact(case: StressCase, spec: Any, record: dict[str, Any]) -> None:
    from threadpoolctl import threadpool_limits

    # one BLAS thread, as ddsolve.solve does (small blocks; see README "Performance notes")
    with threadpool_limits(limits=1, user_api="blas"):
        _solve_contact(case, spec, record)


def _solve_contact(case: StressCase, spec: Any, record: dict[str, Any]) -> None:
    from ddsolve.contact import solve_contact_direct
    from ddsolve.contact.run import run_contact_method
    from ddsolve.prepared import check_decomposition, prepare
    from ddsolve.scene.contact import two_membranes

    check_decomposition(spec)
    scene = None
    if case.load is not None:
        loads = contact_load(case.load, spec.subdomains, spec.elements)
        scene = two_membranes(spec.subdomains, spec.elements, f=loads)
    prepared = prepare(spec, scene=scene)
    scene, problem = prepared.scene, prepared.contact
    h = 1.0 / (spec.subdomains * spec.elements)
    on2 = scene.subdomain_body[scene.element_subdomain] == 1
    f_el = np.broadcast_to(np.asarray(scene.f, dtype=float), on2.shape)
    net = -float(f_el[on2].sum()) * h * h                   # load the contact pressure must carry
    ref = solve_contact_direct(problem)
    sol = ref if spec.method == "direct" else run_contact_method(spec.method, problem, rtol=float(spec.rtol),
                                                                 maxiter=int(spec.maxiter))
    kkt = problem.kkt(sol.u, sol.lam).max
    record["nonfinite"] = [k for k, v in {"u": sol.u, "lambda": sol.lam, "kkt": kkt}.items() if not _finite(v)]
    u_ref, lam_ref = ref.u, ref.lam
    record.update(
        converged=bool(sol.converged), reason=sol.reason, iterations=int(sol.total_iterations),
        error_vs_direct=float(np.linalg.norm(sol.u - u_ref) / max(np.linalg.norm(u_ref), 1e-300)),
        lambda_error=float(np.linalg.norm(sol.lam - lam_ref) / max(np.linalg.norm(lam_ref), 1e-300)),
        force_error=float(abs(sol.lam.sum() - net) / max(abs(net), 1e-300)), net_load=net,
        n_active=int(np.count_nonzero(sol.active)), n_active_direct=int(np.count_nonzero(ref.active)),
        n_contact=int(problem.n_contact), kkt=float(kkt), restarts=0)
    grad = np.asarray(sol.extra.get("gradient_norms", []), dtype=float)
    norm_b = float(sol.extra.get("norm_b", 0.0))
    if grad.size and norm_b > 0:
        record["smalbe_gradient"] = float(grad[-1]) / norm_b
