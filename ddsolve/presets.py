"""Rule sets of the solvers: the one place that maps a preset to solver options (numpy-free).

The solvers implement both the thesis's rules as printed and the project's
improvements on them, selected by keyword arguments whose defaults are the
improved rules. A preset (:data:`ddsolve.options.PRESETS`) names a consistent
choice of these keywords; :func:`solver_options` hands out the keywords of one
method, and :mod:`ddsolve.api`'s runners pass them on.

``"default"``
    The project's rules (no keyword is passed: every solver uses its own defaults).
``"thesis"``
    The literal rules of Lee (2009) wherever the defaults differ
    (docs/methods.md, "The thesis preset"):

    - one-level FETI, FETI-FETI: the orthogonal projection P = I - G (G^T G)^{-1} G^T
      of (2.13) (default: Q-weighted under rho-scaling), ``projection="orthogonal"``;
    - active set method (Chapter 5): every face solve stops at ||r_k|| <= rtol ||r_0||
      (default: rtol max(||r_0||, ||F||), ``face_rtol_rule="initial"``), the initial
      active set {lambda_hat > 0} (default: {lambda_hat > 10 rtol max lambda_hat},
      ``initial_active="positive"``) and the removal of Figure 6.3, the blocking pair (with
      those the step brings to within the sign test's tolerance of 0) per outer iteration
      (default: all negative multipliers at once, ``removal="blocking"``),
      face solves stopped in the plain ||.||_2 of Section 4.4 (default: the gaps weighted
      by max rho, invariant under rho -> s rho and equal to it for rho = 1, ``face_norm="l2"``),
      no redo of a face solve that broke down on the indefinite S~_OL of (4.9)-(4.10)
      (default: redone with the PSD energy form, ``s_ol_fallback=False``), and the sign test
      for penetration relative to ||u||_inf alone (default: also as a force, weighted by the
      stiffness, ``sign_test="plain"``). The acceptance rule (KKT residuals, also weighted by the
      stiffness) is the same under both presets;
    - SMALBE (Section 6.4): the stopping rule ||g^P|| <= eps ||b||, ||G lambda|| <= eps ||b||
      (default: ||G lambda|| <= eps min(||b||, ||e||), ``equality_rule="section-6.4"``),
      rho_bar = ||P F P|| (default 1, ``rho_bar=None``), no FETI-FETI polish
      (``polish=False``), and MPRGP's expansion step of Figure 6.6 as printed (default: preceded by
      Dostál's feasible half step to the boundary, ``halfstep=False``). The project's acceptance check (force balance, KKT
      stationarity) stays enforced: a result that meets the printed rule but fails it is
      reported ``converged=False`` with both facts in the reason, so that no preset calls an
      inaccurate answer converged; its iteration counts are still SMALBE's own.

    - the multibody hybrid method: no second solve with the energy form of S~_OL after a breakdown
      on the indefinite one (default: redone, as the active set method's faces, ``s_ol_fallback=False``;
      a review found 10 of 22 small unstructured scenes breaking down).

Methods whose defaults already are the thesis's rules (fetidp, bddc, the direct solvers) take no option
and run identically under both presets.
"""
from __future__ import annotations

from typing import Any

from .options import PRESETS

#: Solver keywords of the thesis's rules, per (problem, method); absent: no difference.
THESIS_OPTIONS: dict[tuple[str, str], dict[str, Any]] = {
    ("poisson", "feti"): {"projection": "orthogonal"},
    ("multibody", "feti-feti"): {"projection": "orthogonal"},
    ("contact", "active-set"): {"face_rtol_rule": "initial", "initial_active": "positive",
                                "removal": "blocking", "face_norm": "l2", "s_ol_fallback": False,
                                "sign_test": "plain"},
    ("contact", "smalbe"): {"equality_rule": "section-6.4", "rho_bar": None, "polish": False, "halfstep": False},
    ("multibody", "hybrid"): {"s_ol_fallback": False},
}

__all__ = ["THESIS_OPTIONS", "solver_options"]


def solver_options(preset: str, problem: str, method: str) -> dict[str, Any]:
    """The keyword arguments that select ``preset``'s rules in the solver of ``(problem, method)``.

    Parameters
    ----------
    preset : str
        One of :data:`ddsolve.options.PRESETS`.
    problem, method : str
        As in :class:`ddsolve.spec.ProblemSpec`.

    Returns
    -------
    dict
        Empty for ``"default"`` and for methods whose defaults are the thesis's rules;
        a fresh dict (the caller may modify it).

    Raises
    ------
    ValueError
        For an unknown preset.
    """
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r} (choose from {', '.join(PRESETS)})")
    if preset == "default":
        return {}
    return dict(THESIS_OPTIONS.get((problem, method), {}))
