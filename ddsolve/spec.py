"""Problem specification: the validated description of one solve.

A :class:`ProblemSpec` is what the command line, a YAML scene file and the
Snakemake pipeline all produce. :meth:`ProblemSpec.from_mapping` validates every
field and raises :class:`~ddsolve.errors.InputError` naming the first bad one.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import yaml

from .errors import InputError
from .options import CONTACTS, DEFAULT_F, DEFAULT_RTOL, METHODS, NORMS, PCR_METHODS, PROJECTIONS, SCALINGS


def _as_int(field: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise InputError(field, f"must be an integer >= {minimum}, got {value!r}")
    try:
        as_float = float(value)
    except ValueError:
        raise InputError(field, f"must be an integer >= {minimum}, got {value!r}") from None
    if not math.isfinite(as_float) or as_float != int(as_float):
        raise InputError(field, f"must be an integer >= {minimum}, got {value!r}")
    if int(as_float) < minimum:
        raise InputError(field, f"must be an integer >= {minimum}, got {value!r}")
    return int(as_float)


def _as_positive_float(field: str, value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError(field, f"must be a positive number, got {value!r}") from None
    if isinstance(value, bool) or not math.isfinite(out) or out <= 0:
        raise InputError(field, f"must be a positive number, got {value!r}")
    return out


def _choice(field: str, value: Any, choices: tuple[str, ...]) -> str:
    """``value`` as one of ``choices`` (matched case-insensitively, returned as spelled there)."""
    by_lower = {c.lower(): c for c in choices}
    key = value.strip().lower() if isinstance(value, str) else None
    if key not in by_lower:
        raise InputError(field, f"unknown {field} {value!r} (choose from {', '.join(choices)})")
    return by_lower[key]


def parse_rho(value: Any) -> tuple[str, float]:
    """Parse the coefficient specification.

    Parameters
    ----------
    value : float or str
        A positive number (constant coefficient), ``"checkerboard:V"`` (rho
        alternates between 1 and V > 0 across subdomains, like the colours of a
        chess board; for several bodies the board runs across the subdomains
        of all bodies) or ``"body-checkerboard:V"`` (rho constant on each body,
        alternating between 1 and V across bodies: jumps between bodies only).

    Returns
    -------
    (kind, value) : tuple
        ``("constant", rho)``, ``("checkerboard", V)`` or ``("body-checkerboard", V)``.
    """
    if isinstance(value, str) and value.strip().lower().startswith("body-checkerboard"):
        _, _, rest = value.partition(":")
        if not rest:
            raise InputError("rho", f"body-checkerboard needs a value, e.g. 'body-checkerboard:100', got {value!r}")
        return "body-checkerboard", _as_positive_float("rho", rest)
    if isinstance(value, str) and value.strip().lower().startswith("checkerboard"):
        _, _, rest = value.partition(":")
        if not rest:
            raise InputError("rho", f"checkerboard needs a value, e.g. 'checkerboard:100', got {value!r}")
        return "checkerboard", _as_positive_float("rho", rest)
    return "constant", _as_positive_float("rho", value)


def parse_f(value: Any) -> tuple[str, float]:
    """Parse the right-hand side specification.

    Parameters
    ----------
    value : float or str
        A number (constant load) or ``"random:SEED"``: element-wise constant
        loads drawn uniformly from [-1, 1] with numpy's default generator
        seeded by the integer SEED (a generic load that excites the whole
        spectrum, unlike f = 1 on a symmetric decomposition).

        ``"dostal"`` or ``"dostal:F1,F2"`` (contact only): f = F1 on
        (0, 1) x [0.75, 1), F2 on (1, 2) x (0, 0.25), zero elsewhere; the
        benchmark of Dostal et al. with F1 = -3, F2 = -1 by default.

    Returns
    -------
    (kind, value) : tuple
        ``("constant", f)``, ``("random", seed)`` or ``("dostal", (F1, F2))``.
    """
    if isinstance(value, str) and value.strip().lower().startswith("random"):
        _, _, rest = value.partition(":")
        return "random", _as_int("f", rest or "0", 0)
    if isinstance(value, str) and value.strip().lower().startswith("dostal"):
        _, _, rest = value.partition(":")
        return "dostal", parse_dostal(rest)
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InputError("f", f"must be a number or 'random:SEED', got {value!r}") from None
    if isinstance(value, bool) or not math.isfinite(out):
        raise InputError("f", f"must be a finite number or 'random:SEED', got {value!r}")
    return "constant", out


def parse_dostal(rest: str) -> tuple[float, float]:
    """The two patch loads of ``"dostal:F1,F2"`` (empty: the benchmark's (-3, -1))."""
    if not rest.strip():
        return (-3.0, -1.0)
    parts = rest.split(",")
    try:
        values = tuple(float(v) for v in parts)
    except ValueError:
        values = ()
    if len(values) != 2 or not all(math.isfinite(v) for v in values):
        raise InputError("f", f"'dostal:F1,F2' needs two finite numbers, got {rest!r}")
    return values  # type: ignore[return-value]


@dataclass(frozen=True)
class ProblemSpec:
    """A validated problem and solver specification.

    Attributes
    ----------
    problem : str
        ``"poisson"``: -div(rho grad u) = f on the unit square, u = 0 on its
        boundary (one body). ``"multibody"``: problem (4.32), the unit square
        split into bodies x bodies square bodies tied on the active contact area.
        ``"contact"``: model problem (3.1), two membranes (0,1)^2 (clamped at
        x = 0) and (1,2)x(0,1) (floating) with u^2 - u^1 >= 0 on x = 1; each
        split into subdomains x subdomains subdomains; ``bodies`` is 2.
    method : str or None
        None takes the problem's first method. Solver: ``"feti"``, ``"fetidp"``, ``"bddc"``, ``"direct"`` (poisson);
        ``"feti-feti"``, ``"hybrid"``, ``"direct"`` (multibody);
        ``"active-set"`` (with the hybrid method, Chapter 5), ``"smalbe"``
        (SMALBE/MPRGP on the FETI-DP dual, Section 6.4), ``"direct"``
        (primal-dual active set with sparse direct solves) (contact).
    contact : str
        Active area between bodies (multibody): ``"full"`` (case I) or
        ``"middle"`` (case II, middle third of each face).
    bodies : int
        Bodies per side, 1/H_b.
    subdomains : int
        Subdomains per body side, H_b/H_s.
    elements : int
        Q1 elements per subdomain side, H_s/h (at least 2, so that every
        subdomain has interior nodes).
    rho : float or str
        Coefficient: a positive number, ``"checkerboard:V"`` (across subdomains)
        or ``"body-checkerboard:V"`` (across bodies), see :func:`parse_rho`.
    f : float or str or None
        Right-hand side: a constant, or ``"random:SEED"`` (see :func:`parse_f`);
        None takes the problem's default (:data:`DEFAULT_F`).
    scaling : str
        ``"rho"`` (delta-dagger rho-scaling, Section 2.3) or ``"multiplicity"``.
    gamma : float
        Exponent of the rho-scaling, gamma >= 1/2.
    norm : str
        Stopping norm of the hybrid method's PCR: ``"l2"`` (default, the
        thesis's ||r_n||_2 / ||r_0||_2 < rtol, used for Table 4.2) or ``"M"``
        (||r||_M = <r, M r>^(1/2), M the preconditioner (4.11): the norm PCR
        minimises, invariant under the rho / 1/rho scaling of the two blocks).
        Other methods accept only ``"l2"``.
    projection : str
        Projection onto V^k = ker(G^kT) of the hybrid method:
        ``"orthogonal"`` (default, P^k of Section 4.2), ``"dirichlet"`` or
        ``"lumped"`` (FETI's Q-weighted P = I - QG(G^T Q G)^{-1} G^T with Q the
        multiplier preconditioner M_D^{-1} of (4.11) or its super-lumped
        diagonal; robust for coefficient jumps on floating bodies). Other
        methods accept only ``"orthogonal"``.
    rtol : float or None
        Relative residual tolerance ||r_k|| / ||r_0|| < rtol; None takes the
        problem's default (1e-5 for contact, 1e-6 otherwise).
    maxiter : int
        Iteration limit.
    cond : bool
        Compute Lanczos estimates of the extreme eigenvalues.
    check : bool
        Also solve directly and report the relative energy-norm error.
    """

    problem: str = "poisson"
    method: str | None = None
    bodies: int = 1
    subdomains: int = 2
    elements: int = 4
    rho: float | str = 1.0
    f: float | str | None = None
    contact: str = "full"
    scaling: str = "rho"
    gamma: float = 1.0
    norm: str = "l2"
    projection: str = "orthogonal"
    rtol: float | None = None
    maxiter: int = 1000
    cond: bool = False
    check: bool = False

    def __post_init__(self) -> None:
        # problem-dependent defaults (also when the dataclass is built directly)
        if self.method is None and self.problem in METHODS:
            object.__setattr__(self, "method", METHODS[self.problem][0])
        if self.f is None:
            object.__setattr__(self, "f", DEFAULT_F.get(self.problem, 1.0))
        if self.rtol is None:
            object.__setattr__(self, "rtol", DEFAULT_RTOL.get(self.problem, 1e-6))
        if self.problem == "contact" and self.bodies == 1:
            object.__setattr__(self, "bodies", 2)

    @classmethod
    def fields(cls) -> tuple[str, ...]:
        """Names of all fields."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "ProblemSpec":
        """Validate a mapping (YAML scene, CLI flags) and build a spec.

        Raises
        ------
        InputError
            Naming the first invalid or unknown field.
        """
        if not isinstance(data, Mapping):
            raise InputError("scene", f"must be a mapping of fields, got {type(data).__name__}")
        known = set(cls.fields())
        for key in data:
            if key not in known:
                raise InputError(str(key), f"unknown field (known: {', '.join(sorted(known))})")
        defaults = {f.name: f.default for f in dataclasses.fields(cls)}
        merged = {**defaults, **{k: v for k, v in data.items() if v is not None}}
        if merged["f"] is None:
            merged["f"] = DEFAULT_F.get(str(merged["problem"]).strip().lower(), 1.0)
        if merged["rtol"] is None:
            merged["rtol"] = DEFAULT_RTOL.get(str(merged["problem"]).strip().lower(), 1e-6)

        problem = str(merged["problem"]).strip().lower()
        if problem not in METHODS:
            raise InputError("problem", f"unknown problem {merged['problem']!r} (choose from {', '.join(METHODS)})")
        if merged["method"] is None:
            merged["method"] = METHODS[problem][0]
        method = str(merged["method"]).strip().lower()
        if method not in METHODS[problem]:
            raise InputError("method", f"unknown method {merged['method']!r} for problem {problem!r} "
                                       f"(choose from {', '.join(METHODS[problem])})")
        bodies = _as_int("bodies", merged["bodies"], 1)
        subdomains = _as_int("subdomains", merged["subdomains"], 1)
        elements = _as_int("elements", merged["elements"], 1)
        if problem == "poisson" and bodies != 1:
            raise InputError("bodies", f"problem 'poisson' has exactly one body, got {bodies}")
        if problem == "contact":
            if bodies not in (1, 2):
                raise InputError("bodies", f"problem 'contact' has exactly two bodies (the membranes of (3.1)), "
                                           f"got {bodies}")
            bodies = 2
        if elements < 2:
            raise InputError("elements", f"mesh too small for the decomposition: each subdomain needs "
                                         f">= 2 elements per side to have interior nodes, got {elements}")
        contact = str(merged["contact"]).strip().lower()
        if contact not in CONTACTS:
            raise InputError("contact", f"unknown contact area {merged['contact']!r} (choose from {', '.join(CONTACTS)})")
        rho = merged["rho"]
        parse_rho(rho)
        f = merged["f"]
        f_kind = parse_f(f)[0]
        if f_kind == "constant":
            f = float(f)
        if f_kind == "dostal" and problem != "contact":
            raise InputError("f", f"'dostal' loads are defined for problem 'contact' only, not {problem!r}")
        scaling = str(merged["scaling"]).strip().lower()
        if scaling not in SCALINGS:
            raise InputError("scaling", f"unknown scaling {merged['scaling']!r} (choose from {', '.join(SCALINGS)})")
        gamma = _as_positive_float("gamma", merged["gamma"])
        if gamma < 0.5:
            raise InputError("gamma", f"must be >= 1/2 (Section 2.3), got {gamma}")
        norm = _choice("norm", merged["norm"], NORMS)
        projection = _choice("projection", merged["projection"], PROJECTIONS)
        for field, value, default in (("norm", norm, NORMS[0]), ("projection", projection, PROJECTIONS[0])):
            if value != default and method not in PCR_METHODS:
                raise InputError(field, f"{value!r} applies to the hybrid method only, not {method!r} "
                                        f"(use {default!r})")
        rtol = _as_positive_float("rtol", merged["rtol"])
        if rtol >= 1:
            raise InputError("rtol", f"must be in (0, 1), got {rtol}")
        maxiter = _as_int("maxiter", merged["maxiter"], 1)
        for flag in ("cond", "check"):
            if not isinstance(merged[flag], bool):
                raise InputError(flag, f"must be true or false, got {merged[flag]!r}")
        return cls(problem=problem, method=method, bodies=bodies, subdomains=subdomains,
                   elements=elements, rho=rho, f=f, contact=contact, scaling=scaling, gamma=gamma, norm=norm,
                   projection=projection, rtol=rtol, maxiter=maxiter, cond=merged["cond"], check=merged["check"])

    @classmethod
    def from_yaml(cls, path: str | Path, overrides: Mapping[str, Any] | None = None) -> "ProblemSpec":
        """Read a YAML scene file; ``overrides`` (e.g. CLI flags) take precedence."""
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise InputError("scene", f"cannot read {str(path)!r}: {exc.strerror}") from None
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            where = getattr(exc, "problem_mark", None)
            at = f" at line {where.line + 1}" if where is not None else ""
            raise InputError("scene", f"malformed YAML in {str(path)!r}{at}") from None
        if data is None:
            data = {}
        if not isinstance(data, Mapping):
            raise InputError("scene", f"{str(path)!r} must hold a mapping of fields, got {type(data).__name__}")
        return cls.from_mapping({**data, **(overrides or {})})

    def to_dict(self) -> dict[str, Any]:
        """All fields as a plain dictionary."""
        return dataclasses.asdict(self)
