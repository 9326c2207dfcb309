"""Stress study, the criteria: :data:`CRITERIA` judges each record PASS/FAIL (:func:`evaluate`).

Some criteria compare a record with its baseline case (e.g. the iterations at rho = 1).
"""
from __future__ import annotations

import math
from typing import Any, Callable, Mapping, Sequence

# The one policy constant of the true residual (ddsolve.solve marks a solve whose
# recomputed residual exceeds it as not converged).
from ddsolve.krylov import TRUE_RESIDUAL_FACTOR

__all__ = ["CRITERIA", "Verdict", "evaluate"]

#: Iterations under rho-scaling may exceed those at rho = 1 by at most this factor.
ROBUST_FACTOR = 1.5
#: Multiplicity scaling counts as "not robust" beyond ROBUST_FACTOR x the iterations
#: or this factor x the condition estimate of rho = 1.
COND_GROWTH = 10.0
#: Converged iterative solves: error_vs_direct <= ERROR_FACTOR * rtol.
ERROR_FACTOR = 100.0
#: The recomputed residual may exceed max(recursive residual, rtol) by at most this factor.
TRUE_FACTOR = TRUE_RESIDUAL_FACTOR
#: The direct contact reference: KKT residual and relative force-balance error bounds.
REFERENCE_KKT = 1e-10
REFERENCE_FORCE = 1e-4

Verdict = tuple[bool, str]


def _short(text: str, limit: int) -> str:
    """``text`` cut to at most ``limit`` characters at a word boundary, with "..." where it was cut (a review:
    notes ended mid-word, "to the tolerance: esti")."""
    text = str(text)
    if len(text) <= limit:
        return text
    cut = text[:limit - 3].rsplit(" ", 1)[0].rstrip(" ,;:(")
    return cut + "..."


def _clean_run(rec: Mapping[str, Any]) -> Verdict | None:
    """FAIL for a crash, a timeout or a silent NaN (non-finite output of a 'converged' solve)."""
    if rec["status"] in ("crash", "timeout"):
        return False, f"{rec['status']}: {rec['error']}"
    if rec["status"] == "ok" and rec["nonfinite"] and rec["converged"]:
        return False, f"converged with non-finite {', '.join(rec['nonfinite'])}"
    if rec["status"] == "ok" and rec["nonfinite"] and not rec["reason"]:
        return False, f"non-finite {', '.join(rec['nonfinite'])} without a reason"
    return None


def _accuracy(rec: Mapping[str, Any]) -> Verdict:
    """Converged, true residual within TRUE_FACTOR of max(recursive, rtol), small error vs direct.

    The error bound is ERROR_FACTOR rtol, times sqrt(cond) where a condition estimate is
    known (the energy-norm error of a solve to a relative residual rtol grows like that).
    """
    if rec["status"] != "ok":
        return False, f"{rec['status']}: {rec['error']}"
    if not rec["converged"]:
        return False, f"not converged: {rec['reason']}"
    rtol = rec["rtol"]
    if rec["true_rel"] is not None and rec["rec_rel"] is not None:
        if rec["true_rel"] > TRUE_FACTOR * max(rec["rec_rel"], rtol):
            return False, f"true residual {rec['true_rel']:.1e} >> recursive {rec['rec_rel']:.1e}"
    err = rec["error_vs_direct"]
    bound = ERROR_FACTOR * rtol * math.sqrt(max(rec["cond"] or 1.0, 1.0))
    if err is None or err > bound:
        return False, f"error vs direct {err} > {bound:.1e}"
    return True, ""


def _ratio(rec: Mapping[str, Any], base: Mapping[str, Any] | None, key: str) -> float | None:
    if base is None or base.get(key) in (None, 0) or rec.get(key) is None:
        return None
    return float(rec[key]) / float(base[key])


def _crit_accurate(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    return _accuracy(rec)


def _crit_robust(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    ok, note = _accuracy(rec)
    ratio = _ratio(rec, base, "iterations")
    if ratio is None:
        return False, note or "no baseline iterations"
    note = (note + "; " if note else "") + f"{ratio:.2f}x iterations of rho = 1"
    return ok and ratio <= ROBUST_FACTOR, note


def _crit_not_robust(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    if rec["status"] != "ok":
        return False, f"{rec['status']}: {rec['error']}"
    if not rec["converged"]:
        return bool(rec["reason"]), f"expected failure seen: no convergence ({_short(rec['reason'], 60)})"
    it = _ratio(rec, base, "iterations")
    cond = _ratio(rec, base, "cond")
    seen = (it is not None and it > ROBUST_FACTOR) or (cond is not None and cond >= COND_GROWTH)
    parts = [f"{it:.2f}x iterations" if it is not None else "", f"{cond:.3g}x cond" if cond is not None else ""]
    note = ", ".join(p for p in parts if p) + " of rho = 1"
    return seen, ("expected non-robustness seen: " if seen else "no non-robustness seen: ") + note


def _crit_scalable(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    ok, note = _accuracy(rec)
    ratio = _ratio(rec, base, "iterations")
    if ratio is None:
        return False, note or "no baseline"
    note = (note + "; " if note else "") + f"{ratio:.2f}x iterations of the baseline"
    return ok and ratio <= ROBUST_FACTOR, note


def _crit_polylog(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    ok, note = _accuracy(rec)
    if base is None or base.get("cond") is None or rec.get("cond") is None:
        return False, note or "no condition estimates"
    m, m0 = rec["spec"]["elements"], base["spec"]["elements"]
    bound = ((1 + math.log(m)) / (1 + math.log(m0))) ** 2
    ratio = rec["cond"] / base["cond"]
    note = (note + "; " if note else "") + f"cond ratio {ratio:.2f} <= {bound:.2f}"
    return ok and ratio <= bound, note


def _rejected(rec: Mapping[str, Any]) -> Verdict | None:
    """PASS for an input error the case allows (``expect_message``), e.g. a load the scene rejects."""
    want = rec.get("expect_message")
    if rec["status"] == "input_error" and want and want in rec["error"] and "\n" not in rec["error"]:
        return True, f"rejected as input: {_short(rec['error'], 90)}"
    return None


def _crit_contact_reference(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    if _rejected(rec):
        return _rejected(rec)
    if rec["status"] != "ok":
        return False, f"{rec['status']}: {rec['error']}"
    notes = []
    if not rec["converged"]:
        notes.append(f"not converged: {rec['reason']}")
    if rec["kkt"] > REFERENCE_KKT:
        notes.append(f"KKT {rec['kkt']:.1e} > {REFERENCE_KKT:g}")
    if rec["force_error"] > REFERENCE_FORCE:
        notes.append(f"contact force off the net load by {rec['force_error']:.1e}")
    want = rec.get("expect_active")
    if want == "all" and rec["n_active"] != rec["n_contact"]:
        notes.append(f"{rec['n_active']} of {rec['n_contact']} pairs active, designed: all")
    if want == "1" and rec["n_active"] != 1:
        notes.append(f"{rec['n_active']} pairs active, designed: 1")
    zone = f"{rec['n_active']}/{rec['n_contact']} active, force error {rec['force_error']:.1e}"
    return not notes, "; ".join(notes) if notes else zone


def _crit_contact_agree(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    if _rejected(rec):
        return _rejected(rec)
    if rec["status"] != "ok":
        return False, f"{rec['status']}: {rec['error']}"
    if not rec["converged"]:
        return bool(rec["reason"]), f"failed cleanly: {_short(rec['reason'], 70)}"
    tol = ERROR_FACTOR * rec["rtol"]
    notes = []
    if rec["error_vs_direct"] > tol:
        notes.append(f"u error {rec['error_vs_direct']:.1e}")
    if rec["lambda_error"] > tol:
        notes.append(f"lambda error {rec['lambda_error']:.1e}")
    if rec["n_active"] != rec["n_active_direct"]:
        notes.append(f"{rec['n_active']} active vs {rec['n_active_direct']}")
    if notes:
        return False, "converged=True but disagrees with direct: " + ", ".join(notes) + f" (> {tol:.0e})"
    return True, (f"{rec['n_active']}/{rec['n_contact']} active, lambda error {rec['lambda_error']:.1e}, "
                  f"force error {rec['force_error']:.1e}")


def _crit_input_error(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    if rec["status"] != "input_error":
        return False, f"expected an input error, got status {rec['status']} ({rec['reason'] or rec['error']})"
    msg = rec["error"]
    want = rec.get("expect_message") or ""
    ok = "\n" not in msg and want in msg
    return ok, _short(msg, 110)


def _crit_not_converged(rec: Mapping[str, Any], base: Mapping[str, Any] | None) -> Verdict:
    if rec["status"] != "ok":
        return False, f"{rec['status']}: {rec['error']}"
    if rec["converged"]:
        return False, f"claims convergence: {rec['reason']}"
    return bool(rec["reason"]), _short(rec["reason"], 110)


#: Criterion key -> (the rule in words, its check(record, baseline record) -> (passed, note)).
CRITERIA: dict[str, tuple[str, Callable[[Mapping[str, Any], Mapping[str, Any] | None], Verdict]]] = {
    "accurate": (f"converged; true residual <= {TRUE_FACTOR:g} max(recursive, rtol); "
                 f"error vs direct <= {ERROR_FACTOR:g} rtol max(1, sqrt(cond))", _crit_accurate),
    "robust": (f"accurate, and iterations <= {ROBUST_FACTOR:g}x those of rho = 1", _crit_robust),
    "not_robust": (f"clean run showing the predicted non-robustness: iterations > {ROBUST_FACTOR:g}x, "
                   f"or cond >= {COND_GROWTH:g}x, those of rho = 1, or no convergence (with a reason)",
                   _crit_not_robust),
    "scalable": (f"accurate, and iterations <= {ROBUST_FACTOR:g}x those of the baseline", _crit_scalable),
    "polylog": ("accurate, and cond / cond(baseline) <= ((1 + log H/h) / (1 + log H/h_baseline))^2",
                _crit_polylog),
    "contact_reference": (f"converged; KKT <= {REFERENCE_KKT:g}; sum(lambda) = net load to {REFERENCE_FORCE:g}; "
                          f"the designed contact zone (roundoff case: or the load is rejected as input)",
                          _crit_contact_reference),
    "contact_agree": (f"converged=False with a reason, or u and lambda within {ERROR_FACTOR:g} rtol of "
                      f"direct and the same active set (roundoff case: or the load is rejected as input)",
                      _crit_contact_agree),
    "input_error": ("InputError with a one-line message naming the field", _crit_input_error),
    "not_converged": ("no exception; converged=False with a reason; no silent NaN", _crit_not_converged),
}


def evaluate(records: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Apply the criteria: each record gets ``outcome`` ("PASS"/"FAIL") and ``note``.

    Parameters
    ----------
    records : sequence of dict
        Records of :func:`run_case` (baselines among them).

    Returns
    -------
    list of dict
        The records in input order, with ``outcome`` and ``note`` added.
    """
    by_name = {rec["name"]: rec for rec in records}
    rows = []
    for rec in records:
        base = by_name.get(rec["baseline"]) if rec.get("baseline") else None
        verdict = _clean_run(rec)
        if verdict is None:
            if rec.get("baseline") and base is None:
                verdict = (False, f"baseline {rec['baseline']} missing")
            else:
                verdict = CRITERIA[rec["criterion"]][1](rec, base)
        passed, note = verdict
        if rec.get("restarts"):
            note = (note + "; " if note else "") + f"{rec['restarts']} PCR restart(s)"
        rows.append({**rec, "outcome": "PASS" if passed else "FAIL", "note": note})
    return rows
