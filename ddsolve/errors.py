"""Exceptions raised by ddsolve.

Every error caused by bad user input is an :class:`InputError`. Its message is
one short line that names the offending field, so that the command line can
print it as it is and exit with status 2. Offending values are quoted with
:func:`brief` (a bounded ``repr``: a 10 MB string or an alias-expanded YAML
structure is never rendered whole), and :class:`InputError` itself clips the
field and the message and escapes control characters and unencodable text, so
that no input can make the error longer than :data:`MAX_FIELD` +
:data:`MAX_MESSAGE` characters or spread it over several lines.
"""
from __future__ import annotations

import reprlib
from typing import Any

#: Longest rendering of an offending value inside a message (characters).
MAX_VALUE = 80
#: Longest field name printed (characters).
MAX_FIELD = 32
#: Longest message printed after the field (characters): room for the longest message ddsolve writes (with
#: its values, each at most MAX_VALUE); it bounds hostile input, it must not cut ddsolve's own sentences.
MAX_MESSAGE = 300

_repr = reprlib.Repr()
_repr.maxstring = MAX_VALUE
_repr.maxother = MAX_VALUE
_repr.maxlong = 40
_repr.maxlevel = 2
_repr.maxlist = _repr.maxtuple = _repr.maxset = _repr.maxdict = 4


def clip(text: str, limit: int) -> str:
    """``text`` on one line, at most ``limit`` characters (middle elided with ``...``).

    Control characters (newlines included) and text that cannot be encoded as
    UTF-8 (lone surrogates from undecodable command-line bytes) are escaped.
    """
    if len(text) > 4 * limit:                 # escape only what can be shown
        text = text[:2 * limit] + text[-2 * limit:]
    text = text.encode("utf-8", "backslashreplace").decode("utf-8")
    text = "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)
    if len(text) <= limit:
        return text
    head = (limit - 3) * 2 // 3
    return text[:head] + "..." + text[len(text) - (limit - 3 - head):]


def brief(value: Any) -> str:
    """A bounded ``repr`` of an offending value: at most :data:`MAX_VALUE` characters.

    Nested containers are shown to depth 2 with at most 4 items each, so that
    the cost does not depend on the size of ``value`` (a YAML alias bomb
    expands to a huge structure only if it is walked).
    """
    try:
        text = _repr.repr(value)
    except Exception:                          # a hostile __repr__
        text = f"<{type(value).__name__}>"
    return clip(text, MAX_VALUE)


class InputError(ValueError):
    """Invalid user input (scene, configuration or solver options).

    Parameters
    ----------
    field : str
        Name of the offending field, e.g. ``"subdomains"``.
    message : str
        What is wrong, in one line. Quote offending values with :func:`brief`;
        the message is clipped to :data:`MAX_MESSAGE` characters regardless.
    """

    def __init__(self, field: str, message: str) -> None:
        self.field = clip(str(field), MAX_FIELD)
        self.message = clip(str(message), MAX_MESSAGE)
        super().__init__(f"{self.field}: {self.message}")


class OutputError(InputError):
    """The output file could not be written (no space, a file size limit, a name the file system refuses)
    after the solve finished. Field ``output``; :attr:`result` holds the finished
    :class:`~ddsolve.result.SolveResult`, so that nothing computed is lost (the command line prints it,
    then the error line, and exits with status 2). An existing file at the target is kept."""

    def __init__(self, message: str, result: Any = None) -> None:
        super().__init__("output", message)
        self.result = result


def check_tolerance(name: str, value: Any) -> float:
    """``value`` as a float if it is a real number in (0, 1), else :class:`InputError` naming ``name``.

    The relative tolerances of the substructuring methods (``rtol`` of ``solve_fetidp``,
    ``HybridSolver.solve``, ``solve_contact_active_set``, ``eps`` of ``solve_contact_smalbe``, ...) and
    of :class:`~ddsolve.spec.ProblemSpec` obey the same rule: a tolerance >= 1 stops before the first
    step (``solve_fetidp(rtol=1.5)`` returned "converged" with a 200% error), and 0 is never met.
    """
    import numbers
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(name, f"must be a number in (0, 1), got {brief(value)}")
    out = float(value)
    if not 0.0 < out < 1.0:            # also NaN
        raise InputError(name, f"must be in (0, 1), got {out:g}")
    return out


def check_flag(name: str, value: Any) -> bool:
    """``value`` if it is True or False (numpy's included), else :class:`InputError` naming ``name``
    (``cond="yes"`` was read as True)."""
    import numpy as np
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(name, f"must be True or False, got {brief(value)}")
    return bool(value)


def check_seed(name: str, value: Any) -> int:
    """``value`` as an int if it is an integer that fits METIS's C int seed, else :class:`InputError`
    naming ``name`` (``seed=2**70`` failed inside pymetis with a TypeError)."""
    import numpy as np
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise InputError(name, f"must be an integer, got {brief(value)}")
    if not -2**31 <= int(value) < 2**31:
        raise InputError(name, f"must lie in [-2**31, 2**31 - 1] (METIS's seed), got {value!r}")
    return int(value)


class ConvergenceWarning(UserWarning):
    """A solve that returns without meeting its tolerance (its result says why: ``converged``, ``reason``).

    Raised as a warning, not an exception, by the solvers that hand back a bare
    solution (``DDInverse * f``); ``warnings.simplefilter("error", ConvergenceWarning)``
    turns it into an exception.
    """


__all__ = ["InputError", "OutputError", "ConvergenceWarning", "brief", "check_flag", "check_tolerance", "clip", "MAX_VALUE",
           "MAX_FIELD", "MAX_MESSAGE"]
