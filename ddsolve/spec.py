"""Problem specification: the validated description of one solve.

A :class:`ProblemSpec` is what the command line, a YAML scene file, the Python
API and the Snakemake pipeline all produce. It validates itself when it is
constructed (``ProblemSpec(gamma=-1)`` raises), and
:meth:`ProblemSpec.from_mapping` and :meth:`ProblemSpec.from_yaml` go through
the same validation; every error is an :class:`~ddsolve.errors.InputError`
naming the first bad field.

Fields that do not apply
------------------------
A field whose value is its default is always accepted. A *non-default* value
for a field that the chosen problem or method does not use is an error, never
silently ignored:

- ``contact`` (active area): problem ``multibody`` only, with at least two bodies (or a ``mesh_file``);
- ``rho: body-checkerboard:V``: problems with several bodies (``multibody`` with ``bodies >= 2`` or a ``mesh_file``, ``contact``);
- ``f: dostal[:F1,F2]``: problem ``contact`` only;
- ``cond``: the Krylov methods of poisson and multibody (:data:`COND_METHODS`; the
  hybrid method's PCR has no Lanczos estimate and reports none);
- ``check``, ``scaling``, ``gamma``, ``rtol``, ``maxiter``: not with method ``direct``;
- ``gamma``: scaling ``rho`` only (the exponent of the rho-scaling);
- ``norm``, ``projection``: the hybrid method only;
- ``geometry``, ``maxh``, ``refine``, ``parts``, ``mesh_file``: ``mesh: unstructured`` only
  (``geometry`` and ``maxh`` not with a ``mesh_file``); ``subdomains``, ``elements``:
  ``mesh: structured`` only; ``dirichlet``, ``bodies_materials``, ``contact_boundary``: with a
  ``mesh_file`` only (``contact_boundary``: problem ``contact``; ``bodies``: not with a ``mesh_file``,
  whose materials are the bodies).

Scene files are read with hard limits (:data:`MAX_SCENE_BYTES`, a regular
file, UTF-8, :class:`SceneLoader`'s bounds on nesting and alias expansion), so
a hostile file is refused cheaply.
"""
from __future__ import annotations

import dataclasses
import math
import os
import sys
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping


from .errors import InputError, brief
from .scene_file import MAX_SCENE_BYTES, SceneLoader, read_scene  # noqa: F401  (re-exported)
from .options import (
    CONTACTS,
    DEFAULT_F,
    DEFAULT_RTOL,
    GEOMETRIES,
    MESHES,
    METHODS,
    NORMS,
    PCR_METHODS,
    PRESETS,
    PRIMAL_METHODS,
    PRIMALS,
    PROJECTIONS,
    SCALINGS,
)

#: Default iteration limit.
DEFAULT_MAXITER = 1000
#: Largest integer field value (sizes, iteration limit, random seed).
MAX_INT = 2**31 - 1
#: Defaults of the unstructured-mesh fields: netgen's largest element size, METIS parts per body.
DEFAULT_MAXH = 0.1
DEFAULT_PARTS = 4
#: Most uniform refinements of an unstructured mesh (each quarters every triangle).
MAX_REFINE = 12
#: Longest file path accepted (mesh_file, output).
_MAX_PATH = 4096
#: Methods that accept ``cond`` (hybrid: accepted, since the Chapter 4 studies set it for both methods; it
#: reports none and logs a warning).
COND_METHODS: tuple[str, ...] = ("feti", "fetidp", "bddc", "feti-feti", "hybrid")

#: A decimal number: optional sign, digits with an optional point, optional exponent (no '_', no hex).
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)   # ASCII digits only (not "٤")
_PATTERN = re.compile(r"(?P<kind>body-checkerboard|checkerboard)(?:\s*:\s*(?P<value>.*))?", re.IGNORECASE | re.DOTALL)
_RANDOM = re.compile(r"random(?:\s*:\s*(?P<seed>.*))?", re.IGNORECASE | re.DOTALL)
_DOSTAL = re.compile(r"dostal(?:\s*:(?P<rest>.*))?", re.IGNORECASE | re.DOTALL)
#: Longest string parsed as a number or pattern (longer ones are refused unread).
_MAX_TEXT = 200


def _plain(value: Any) -> Any:
    """Numpy scalars (``np.int64``, ``np.float64``, ``np.bool_``, ``np.str_``) as Python scalars."""
    if type(value).__module__ == "numpy" and getattr(value, "ndim", None) == 0 and hasattr(value, "item"):
        return value.item()
    return value


def _number(field: str, value: Any, what: str) -> float:
    """``value`` (a real number or a decimal string) as a float; InputError(field) otherwise."""
    value = _plain(value)
    if isinstance(value, bool):
        raise InputError(field, f"must be {what}, got {brief(value)}")
    if isinstance(value, int):
        try:
            return float(value)
        except OverflowError:
            raise InputError(field, f"must be {what}, got a {len(str(abs(value)))}-digit integer") from None
    if isinstance(value, float):
        return value
    if isinstance(value, str) and len(value) <= _MAX_TEXT and _NUMBER.fullmatch(value.strip()):
        return float(value.strip())
    raise InputError(field, f"must be {what}, got {brief(value)}")


def _as_int(field: str, value: Any, minimum: int, maximum: int = MAX_INT) -> int:
    """``value`` as an integer in [minimum, maximum] (integral floats and decimal strings accepted)."""
    what = f"an integer in [{minimum}, {maximum}]"
    value = _plain(value)
    if isinstance(value, int) and not isinstance(value, bool):
        out = value
    else:
        as_float = _number(field, value, what)
        if not math.isfinite(as_float) or as_float != int(as_float):
            raise InputError(field, f"must be {what}, got {brief(value)}")
        out = int(as_float)
    if not minimum <= out <= maximum:
        raise InputError(field, f"must be {what}, got {brief(value)}")
    return out


def _not_subnormal(field: str, out: float, value: Any) -> float:
    """Refuse a nonzero value below the smallest normal double: it has fewer significant digits
    (1e-320 keeps about 3), and a load of 1e-320 gave answers 11-13% off, reported converged."""
    if out != 0.0 and abs(out) < sys.float_info.min:
        raise InputError(field, f"{brief(_plain(value))} is below {sys.float_info.min:.3g}, the smallest "
                                f"normal number (rescale the problem)")
    return out


def _as_positive_float(field: str, value: Any) -> float:
    out = _number(field, value, "a positive finite number")
    if not math.isfinite(out) or out <= 0:
        raise InputError(field, f"must be a positive finite number, got {brief(_plain(value))}")
    return _not_subnormal(field, out, value)


def _as_bool(field: str, value: Any) -> bool:
    value = _plain(value)
    if not isinstance(value, bool):
        raise InputError(field, f"must be true or false, got {brief(value)}")
    return value


def _choice(field: str, value: Any, choices: tuple[str, ...], what: str | None = None, where: str = "") -> str:
    """``value`` as one of ``choices`` (matched case-insensitively, returned as spelled there)."""
    by_lower = {c.lower(): c for c in choices}
    value = _plain(value)
    key = value.strip().lower() if isinstance(value, str) else None
    if key not in by_lower:
        raise InputError(field, f"unknown {what or field} {brief(value)}{where} (choose from {', '.join(choices)})")
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
        Pattern names are matched case-insensitively and exactly
        (``"checkerboardz:5"`` is an error).

    Returns
    -------
    (kind, value) : tuple
        ``("constant", rho)``, ``("checkerboard", V)`` or ``("body-checkerboard", V)``.

    Raises
    ------
    InputError
        ``rho``, for anything else.
    """
    value = _plain(value)
    if isinstance(value, str) and len(value) <= _MAX_TEXT:
        text = value.strip()
        match = _PATTERN.fullmatch(text)
        if match:
            kind = match["kind"].lower()
            if not (match["value"] or "").strip():
                raise InputError("rho", f"{kind} needs a value, e.g. '{kind}:100', got {brief(value)}")
            try:
                return kind, _as_positive_float("rho", match["value"])
            except InputError as err:       # name the whole value, not only V
                raise InputError("rho", f"{kind}:V needs a positive finite V, got {brief(value)}"
                                        f"{' (subnormal)' if 'smallest normal' in err.message else ''}") from None
        if text[:1].isalpha():
            raise InputError("rho", f"must be a positive number, 'checkerboard:V' or 'body-checkerboard:V', "
                                    f"got {brief(value)}")
    return "constant", _as_positive_float("rho", value)


def parse_f(value: Any) -> tuple[str, Any]:
    """Parse the right-hand side specification.

    Parameters
    ----------
    value : float or str
        A number (constant load) or ``"random:SEED"`` (``"random"``: seed 0):
        element-wise constant loads drawn uniformly from [-1, 1] with numpy's
        default generator seeded by the integer SEED (a generic load that
        excites the whole spectrum, unlike f = 1 on a symmetric decomposition).

        ``"dostal"`` or ``"dostal:F1,F2"`` (contact only): f = F1 on
        (0, 1) x [0.75, 1), F2 on (1, 2) x (0, 0.25), zero elsewhere; the
        benchmark of Dostal et al. with F1 = -3, F2 = -1 by default.

    Returns
    -------
    (kind, value) : tuple
        ``("constant", f)``, ``("random", seed)`` or ``("dostal", (F1, F2))``.

    Raises
    ------
    InputError
        ``f``, for anything else.
    """
    value = _plain(value)
    if isinstance(value, str) and len(value) <= _MAX_TEXT:
        text = value.strip()
        match = _RANDOM.fullmatch(text)
        if match:
            seed = match["seed"]
            if seed is not None and not re.fullmatch(r"\s*\d+\s*", seed):
                raise InputError("f", f"'random:SEED' needs an integer seed in [0, {MAX_INT}], got {brief(value)}")
            return "random", _as_int("f", (seed or "0").strip(), 0)
        match = _DOSTAL.fullmatch(text)
        if match:
            if match["rest"] is not None and not match["rest"].strip():    # 'dostal:' read as 'dostal' (a review)
                raise InputError("f", f"'dostal:F1,F2' needs two finite numbers after the colon, got {brief(value)}"
                                      " (plain 'dostal': the benchmark's -3, -1)")
            return "dostal", parse_dostal(match["rest"] or "")
    out = _number("f", value, "a number, 'random:SEED' or 'dostal:F1,F2'")
    if not math.isfinite(out):
        raise InputError("f", f"must be a finite number, 'random:SEED' or 'dostal:F1,F2', got {brief(value)}")
    return "constant", _not_subnormal("f", out, value)


def parse_dostal(rest: str) -> tuple[float, float]:
    """The two patch loads of ``"dostal:F1,F2"`` (empty: the benchmark's (-3, -1))."""
    if not rest.strip():
        return (-3.0, -1.0)
    parts = [p.strip() for p in rest.split(",")]
    if len(parts) != 2 or not all(_NUMBER.fullmatch(p) for p in parts):
        raise InputError("f", f"'dostal:F1,F2' needs two finite numbers, got {brief(rest)}")
    values = (float(parts[0]), float(parts[1]))
    if not all(math.isfinite(v) for v in values):
        raise InputError("f", f"'dostal:F1,F2' needs two finite numbers, got {brief(rest)}")
    return (_not_subnormal("f", values[0], parts[0]), _not_subnormal("f", values[1], parts[1]))


def _inapplicable(field: str, value: Any, why: str) -> InputError:
    """The error of a non-default value of a field that the problem or method does not use."""
    shown = "true" if value is True else brief(value)
    return InputError(field, f"{shown} does not apply: {why} (only the default is accepted)")


def _validated(raw: Mapping[str, Any]) -> dict[str, Any]:
    """The normalised fields of a spec, or InputError naming the first bad one (in field order).

    ``raw`` holds every field; ``None`` for ``method``, ``f`` and ``rtol``
    takes the problem's default.
    """
    problem = _choice("problem", raw["problem"], tuple(METHODS))
    method = raw["method"]
    method = METHODS[problem][0] if method is None else _choice(
        "method", method, METHODS[problem], where=f" for problem {problem!r}")
    bodies = _as_int("bodies", raw["bodies"], 1)
    if problem == "poisson" and bodies != 1:
        raise InputError("bodies", f"problem 'poisson' has exactly one body, got {bodies}")
    if problem == "contact":
        if bodies not in (1, 2):
            raise InputError("bodies", f"problem 'contact' has exactly two bodies (the membranes of (3.1)), "
                                       f"got {bodies}")
        bodies = 2
    subdomains = _as_int("subdomains", raw["subdomains"], 1)
    # the range of the docs and the schema, [2, ...], and for an integer below it the reason (a review: 0 said
    # "[1, ...]" and 1 "mesh too small")
    try:
        elements = _as_int("elements", raw["elements"], -MAX_INT)
    except InputError:
        raise InputError("elements", f"must be an integer in [2, {MAX_INT}], got {brief(_plain(raw['elements']))}"
                         ) from None
    if elements < 2:
        raise InputError("elements", f"must be an integer in [2, {MAX_INT}], got {elements} (each subdomain "
                                     f"needs >= 2 elements per side to have interior nodes)")
    rho = _plain(raw["rho"])
    rho_kind = parse_rho(rho)[0]
    if rho_kind == "body-checkerboard" and problem == "poisson":
        raise _inapplicable("rho", rho, "problem 'poisson' has one body (use checkerboard:V)")
    f = _plain(raw["f"])
    if f is None:
        f = DEFAULT_F.get(problem, 1.0)
    f_kind, f_value = parse_f(f)
    if f_kind == "constant":
        f = f_value
    if f_kind == "dostal" and problem != "contact":
        raise InputError("f", f"'dostal' loads are defined for problem 'contact' only, not {problem!r}")
    contact = _choice("contact", raw["contact"], CONTACTS, what="contact area")
    if contact != CONTACTS[0] and problem != "multibody":
        raise _inapplicable("contact", contact, f"the active area is a field of problem 'multibody', not {problem!r}")
    if problem == "multibody" and bodies == 1 and raw.get("mesh_file") in (None, ""):
        # one body: no inter-body interface (both were ignored; poisson refuses body-checkerboard already)
        if contact != CONTACTS[0]:
            raise _inapplicable("contact", contact, "one body has no inter-body interface (use bodies >= 2)")
        if rho_kind == "body-checkerboard":
            raise _inapplicable("rho", rho, "one body has nothing to alternate with (use checkerboard:V)")
    direct = method == "direct"
    scaling = _choice("scaling", raw["scaling"], SCALINGS)
    if scaling != SCALINGS[0] and direct:
        raise _inapplicable("scaling", scaling, "method 'direct' has no interface scaling")
    gamma = _as_positive_float("gamma", raw["gamma"])
    if gamma < 0.5:
        raise InputError("gamma", f"must be >= 1/2 (Section 2.3), got {gamma!r}")
    if gamma != 1.0 and (direct or scaling != "rho"):
        raise _inapplicable("gamma", gamma, "it is the exponent of the rho-scaling" if not direct
                            else "method 'direct' has no interface scaling")
    norm = _choice("norm", raw["norm"], NORMS)
    projection = _choice("projection", raw["projection"], PROJECTIONS)
    for field, value, default in (("norm", norm, NORMS[0]), ("projection", projection, PROJECTIONS[0])):
        if value != default and method not in PCR_METHODS:
            raise InputError(field, f"{value!r} applies to the hybrid method only, not {method!r} "
                                    f"(use {default!r})")
    default_rtol = DEFAULT_RTOL.get(problem, 1e-6)
    rtol = default_rtol if raw["rtol"] is None else _as_positive_float("rtol", raw["rtol"])
    if rtol >= 1:
        raise InputError("rtol", f"must be in (0, 1), got {rtol!r}")
    if rtol != default_rtol and direct:
        raise _inapplicable("rtol", rtol, "method 'direct' does not iterate")
    maxiter = _as_int("maxiter", raw["maxiter"], 1)
    if maxiter != DEFAULT_MAXITER and direct:
        raise _inapplicable("maxiter", maxiter, "method 'direct' does not iterate")
    cond = _as_bool("cond", raw["cond"])
    if cond and method not in COND_METHODS:
        raise _inapplicable("cond", cond, f"method {method!r} computes no Lanczos estimate")
    check = _as_bool("check", raw["check"])
    if check and direct:
        raise _inapplicable("check", check, "method 'direct' is the direct solve")
    out = dict(problem=problem, method=method, bodies=bodies, subdomains=subdomains, elements=elements,
               rho=rho, f=f, contact=contact, scaling=scaling, gamma=gamma, norm=norm, projection=projection,
               rtol=rtol, maxiter=maxiter, cond=cond, check=check,
               preset=_choice("preset", raw["preset"], PRESETS))
    out.update(_validated_mesh(raw, problem))
    return out


def _path_text(field: str, value: Any) -> str:
    """A file path field: a string ('' or None: none), stripped, at most :data:`_MAX_PATH` characters."""
    value = _plain(value)
    if value is None:
        return ""
    if isinstance(value, os.PathLike):          # pathlib.Path from the Python API
        value = os.fspath(value)
    if not isinstance(value, str) or len(value) > _MAX_PATH or "\x00" in value:
        raise InputError(field, f"must be a file path, got {brief(value)}")
    return value.strip()


def _check_writable(directory: str) -> None:
    """Refuse an ``output`` whose directory takes no new file (read-only, /proc, no permission) before
    the solve, not after it: the writer creates a temporary file there and renames it."""
    import tempfile

    try:
        with tempfile.NamedTemporaryFile(dir=directory, prefix=".ddsolve-check-", suffix=".tmp"):
            pass
    except OSError as exc:
        raise InputError("output", f"cannot write in directory {brief(directory)}: {exc.strerror or exc}") from None


def _names_text(field: str, value: Any, default: str) -> str:
    """Comma-separated names (netgen boundaries or materials), normalised to 'a,b'."""
    value = _plain(value)
    if value is None:
        return default
    if isinstance(value, (list, tuple)):
        value = ",".join(str(_plain(v)) for v in value)
    if not isinstance(value, str) or len(value) > _MAX_TEXT:
        raise InputError(field, f"must be comma-separated names, got {brief(value)}")
    names = [n.strip() for n in value.split(",")]
    if value.strip() and not all(names):
        raise InputError(field, f"empty name in {brief(value)}")
    return ",".join(names) if value.strip() else ""


def _validated_mesh(raw: Mapping[str, Any], problem: str) -> dict[str, Any]:
    """The unstructured-mesh fields (``mesh`` ... ``output``), validated against the structured ones."""
    mesh = _choice("mesh", raw["mesh"], MESHES)
    unstructured = mesh == "unstructured"
    mesh_file = _path_text("mesh_file", raw["mesh_file"])
    if mesh_file:
        if not unstructured:
            raise _inapplicable("mesh_file", mesh_file, "a netgen mesh file needs mesh 'unstructured'")
        if not os.path.isfile(mesh_file):
            what = ("is a directory" if os.path.isdir(mesh_file) else
                    "is not a regular file" if os.path.exists(mesh_file) else "")
            raise InputError("mesh_file", f"{brief(mesh_file)} {what}" if what else f"no such file: {brief(mesh_file)}")
        if not mesh_file.lower().endswith((".vol", ".vol.gz")):       # netgen reads by the name's suffix
            raise InputError("mesh_file", f"must be a netgen mesh (.vol or .vol.gz), got {brief(mesh_file)}")
        contact = _choice("contact", raw["contact"], CONTACTS, what="contact area")
        if contact != CONTACTS[0]:
            raise _inapplicable("contact", contact, "a mesh file ties every inter-body interface (its named "
                                                    "boundaries say where)")
    why_structured = "it applies to mesh 'unstructured' only"
    default_geometry = GEOMETRIES[problem][0]
    geometry = default_geometry if raw["geometry"] is None else _choice(
        "geometry", raw["geometry"], GEOMETRIES[problem], where=f" for problem {problem!r}")
    maxh = _as_positive_float("maxh", raw["maxh"])
    for field, value, default in (("geometry", geometry, default_geometry), ("maxh", maxh, DEFAULT_MAXH)):
        if value != default and not unstructured:
            raise _inapplicable(field, value, why_structured)
        if value != default and mesh_file:
            raise _inapplicable(field, value, "the mesh comes from mesh_file")
    refine = _as_int("refine", raw["refine"], 0, MAX_REFINE)
    parts = _as_int("parts", raw["parts"], 1)
    for field, value, default in (("refine", refine, 0), ("parts", parts, DEFAULT_PARTS)):
        if value != default and not unstructured:
            raise _inapplicable(field, value, why_structured)
    if unstructured:
        for field, default in (("subdomains", 2), ("elements", 4)):
            value = _as_int(field, raw[field], 1)
            if value != default:
                raise _inapplicable(field, value, "an unstructured mesh is sized by maxh/refine and split "
                                                  "into 'parts' METIS subdomains per body")
        if mesh_file and _as_int("bodies", raw["bodies"], 1) not in (1, 2 if problem == "contact" else 1):
            raise _inapplicable("bodies", raw["bodies"], "the bodies of a mesh_file are its materials "
                                                         "(see bodies_materials)")
    dirichlet = _names_text("dirichlet", raw["dirichlet"], "boundary")
    if not dirichlet:        # an empty --dirichlet "" meant the whole boundary, silently
        raise InputError("dirichlet", "is empty: name the boundaries with u = 0, or 'boundary' for the whole "
                                      "outer boundary")
    bodies_materials = _names_text("bodies_materials", raw["bodies_materials"], "")
    contact_boundary = _names_text("contact_boundary", raw["contact_boundary"], "contact") or "contact"
    if "," in contact_boundary:
        raise InputError("contact_boundary", f"one boundary name, got {brief(contact_boundary)}")
    for field, value, default in (("dirichlet", dirichlet, "boundary"), ("bodies_materials", bodies_materials, ""),
                                  ("contact_boundary", contact_boundary, "contact")):
        if value != default and not mesh_file:
            raise _inapplicable(field, value, "it names parts of a mesh_file")
    if contact_boundary != "contact" and problem != "contact":
        raise _inapplicable("contact_boundary", contact_boundary, "problem 'contact' only")
    primal = _choice("primal", raw["primal"], PRIMALS, what="primal constraints")
    method = METHODS[problem][0] if raw["method"] is None else _choice("method", raw["method"], METHODS[problem])
    if primal != PRIMALS[0] and method not in PRIMAL_METHODS:
        raise _inapplicable("primal", primal, f"method {method!r} has no primal constraints "
                                              f"({' and '.join(PRIMAL_METHODS)} only)")
    output = _path_text("output", raw["output"])
    if output:
        if not output.lower().endswith(".vtu"):
            raise InputError("output", f"must be a .vtu file (ParaView), got {brief(output)}")
        name = os.path.basename(output)
        if name.lower() == ".vtu":              # the writer read '.vtu' as a hidden file without a suffix
            raise InputError("output", f"needs a file name before '.vtu', got {brief(output)}")
        # a symbolic link is written through (ddsolve.io.cleanup.resolved_target): its target's directory
        # must exist (a review: a dangling link to nowhere/x.vtu created the directory nowhere/)
        # a symbolic link is written through (ddsolve.io.cleanup.resolved_target): its target's directory
        # must exist (a review: a dangling link to nowhere/x.vtu created the directory nowhere/); os.path.islink,
        # not resolved_target, whose Path.is_symlink raises on a name too long (refused below, in one line)
        target = os.path.realpath(output) if os.path.islink(output) else output
        if os.path.islink(output) and not target.lower().endswith(".vtu"):
            raise InputError("output", f"{brief(output)} is a symbolic link to {brief(target)}, which is not a "
                                       f".vtu file (the link is written through)")
        parent = os.path.dirname(os.path.abspath(target))
        try:
            name_max = os.pathconf(parent, "PC_NAME_MAX") if os.path.isdir(parent) else 255
        except (OSError, ValueError):
            name_max = 255
        if len(os.fsencode(name)) > name_max:    # refused by the rename after the solve (a review)
            raise InputError("output", f"file name of {len(os.fsencode(name))} bytes, longer than the "
                                       f"{name_max} the file system takes: {brief(name)}")
        if not os.path.isdir(parent):
            # a path through a file: name the file, not a missing directory (a review)
            above = parent
            while above and not os.path.exists(above) and os.path.dirname(above) != above:
                above = os.path.dirname(above)
            if os.path.exists(above) and not os.path.isdir(above):
                raise InputError("output", f"{brief(above)} is a file, not a directory")
            raise InputError("output", f"directory {brief(parent)} does not exist")
        if os.path.isdir(output):
            raise InputError("output", f"{brief(output)} is a directory")
        _check_writable(parent)
    return dict(mesh=mesh, geometry=geometry, maxh=maxh, refine=refine, parts=parts, mesh_file=mesh_file,
                dirichlet=dirichlet, contact_boundary=contact_boundary, bodies_materials=bodies_materials,
                primal=primal, output=output)


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
    preset : str
        Rule set (:mod:`ddsolve.presets`): ``"default"`` (the project's improved
        rules) or ``"thesis"`` (the thesis's rules as printed wherever they
        differ: FETI and FETI-FETI, the active set method, SMALBE). Accepted
        for every method; those whose defaults are the thesis's rules run
        identically under both.
    mesh : str
        ``"structured"`` (default: the Q1 squares above) or ``"unstructured"``
        (netgen P1 triangles, each body split into ``parts`` METIS subdomains,
        :mod:`ddsolve.scene.unstructured`). ``checkerboard:V`` on an
        unstructured mesh gives rho = V on the odd-numbered METIS parts of each
        body; ``body-checkerboard:V`` alternates over the body grid (multibody)
        or the body index (contact, mesh files).
    geometry : str or None
        Built-in unstructured geometry (:data:`~ddsolve.options.GEOMETRIES`):
        poisson ``square``/``lshape``/``hole``, multibody ``square``, contact
        ``membranes``; None takes the problem's first.
    maxh : float
        netgen's largest element size before refinement.
    refine : int
        Uniform refinements (each quarters every triangle), 0..MAX_REFINE.
    parts : int
        METIS subdomains per body.
    mesh_file : str
        A user's 2-D netgen mesh (``.vol``/``.vol.gz``): its materials are the
        bodies (``bodies_materials``), named boundaries carry u = 0
        (``dirichlet``) and the contact interface (``contact_boundary``).
        For multibody every inter-body interface is tied; for contact the file
        must have two bodies, the first clamped.
    dirichlet : str
        Comma-separated boundary names of ``mesh_file`` with u = 0;
        ``"boundary"`` (default): the whole outer boundary.
    contact_boundary : str
        Name of the contact interface of ``mesh_file`` (problem contact).
    bodies_materials : str
        Comma-separated material names of ``mesh_file`` in body order
        (default ``""``: every material, in mesh order).
    primal : str
        Primal constraints of FETI-DP/BDDC: ``"vertices"`` (edge averages are
        not available yet).
    output : str
        A ``.vtu`` file for ParaView (solution, subdomain ids, contact
        multipliers); ``""``: none.
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
    maxiter: int = DEFAULT_MAXITER
    cond: bool = False
    check: bool = False
    preset: str = "default"
    # unstructured meshes and output (ddsolve.scene.unstructured, ddsolve.io.vtk)
    mesh: str = "structured"
    geometry: str | None = None
    maxh: float = DEFAULT_MAXH
    refine: int = 0
    parts: int = DEFAULT_PARTS
    mesh_file: str = ""
    dirichlet: str = "boundary"
    contact_boundary: str = "contact"
    bodies_materials: str = ""
    primal: str = "vertices"
    output: str = ""

    def __post_init__(self) -> None:
        # One validation for the constructor, from_mapping, from_yaml and dataclasses.replace;
        # it also fills the problem-dependent defaults (method, f, rtol; bodies = 2 for contact).
        for name, value in _validated({f.name: getattr(self, f.name) for f in dataclasses.fields(self)}).items():
            object.__setattr__(self, name, value)

    @classmethod
    def fields(cls) -> tuple[str, ...]:
        """Names of all fields."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "ProblemSpec":
        """Validate a mapping (YAML scene, CLI flags) and build a spec.

        Keys must be field names; a value ``None`` takes the field's default.

        Raises
        ------
        InputError
            Naming the first invalid or unknown field.
        """
        if not isinstance(data, Mapping):
            raise InputError("scene", f"must be a mapping of fields, got {type(data).__name__}")
        known = cls.fields()
        for key in data:
            if not isinstance(key, str) or key not in known:
                raise InputError(str(key) if isinstance(key, str) else brief(key),
                                 f"unknown field (known: {', '.join(known)})")
        return cls(**{k: v for k, v in data.items() if v is not None})

    @classmethod
    def from_yaml(cls, path: str | Path, overrides: Mapping[str, Any] | None = None) -> "ProblemSpec":
        """Read a YAML scene file (:func:`read_scene`); ``overrides`` (e.g. CLI flags) take precedence."""
        spec = cls.from_mapping({**read_scene(path), **(overrides or {})})
        if spec.output and os.path.abspath(spec.output) == os.path.abspath(path) or (
                spec.output and os.path.exists(spec.output) and os.path.samefile(spec.output, path)):
            # the solution would replace the scene that asked for it (a review: rc 0, the scene file gone)
            raise InputError("output", f"{brief(spec.output)} is the scene file itself")
        return spec

    def to_dict(self) -> dict[str, Any]:
        """All fields as a plain dictionary."""
        return dataclasses.asdict(self)
