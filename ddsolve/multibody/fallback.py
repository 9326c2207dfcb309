"""The energy form of S~_OL after a breakdown on the indefinite one (docs/methods.md, item 12a).

S~_OL = S_GG - S_G0 M_0 S_0G of (4.9)-(4.10) can be indefinite, and PCR then breaks down on the
preconditioner (4.11). The active set method's face solves and the multibody hybrid method (serial and
distributed) then solve again with the PSD energy form, ``s_ol="energy"``; the thesis preset does not
(``s_ol_fallback=False``).
"""
from __future__ import annotations

import logging
from typing import Any, Callable

__all__ = ["broke_down_on_s_ol", "with_s_ol_fallback"]

log = logging.getLogger(__name__)


def broke_down_on_s_ol(krylov: Any) -> bool:
    """Whether a hybrid solve with ``s_ol="thesis"`` ended in PCR's breakdown on an indefinite preconditioner."""
    return (not krylov.converged and krylov.reason.startswith("breakdown")
            and "M not positive definite" in krylov.reason)


def with_s_ol_fallback(solve: Callable[[str], Any], s_ol_fallback: bool = True) -> Any:
    """``solve("thesis")``, and ``solve("energy")`` if that broke down on S~_OL and ``s_ol_fallback``.

    ``solve`` returns a :class:`~ddsolve.dd.common.MethodOutput` or a tuple whose first item is one (the
    distributed hybrid method). The second result's reason says that it followed a breakdown, and its
    ``extra["s_ol_breakdown"]`` keeps the first one's reason. A review found the multibody hybrid method
    breaking down on 10 of 22 small unstructured scenes (errors 0.4-20.8).
    """
    def method_output(out: Any) -> Any:
        return out[0] if isinstance(out, tuple) else out

    out = solve("thesis")
    first = method_output(out).krylov
    if not (s_ol_fallback and broke_down_on_s_ol(first)):
        return out
    log.warning("hybrid: %s; solving again with s_ol='energy'", first.reason)
    again = solve("energy")
    second = method_output(again)
    # what the first solve counted stays counted: a solver reports its constructor's factorizations and
    # setup time with its first solve only (a review: the fallback reported 0 factorizations)
    second.n_factorizations += method_output(out).n_factorizations
    second.setup_seconds += method_output(out).setup_seconds
    second.extra["s_ol_breakdown"] = first.reason
    second.krylov.reason = f"{second.krylov.reason} (with s_ol='energy', after a breakdown with s_ol='thesis')"
    return again
