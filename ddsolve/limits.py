"""Resource estimates of a solve, checked before anything is allocated.

:func:`estimate_memory` and :func:`estimate_work` are plain functions of a
:class:`~ddsolve.spec.ProblemSpec` (no assembly, no numpy), so the command
line, the API and the workflow schema can refuse a problem that cannot run on
this machine in microseconds, with one line, instead of dying in an allocation
or hanging in a Python loop. :func:`check_resources` does the refusing.

Model
-----
With ``B`` bodies per side, ``S`` subdomains per body side and ``E`` elements
per subdomain side (contact: two membranes of ``S x S`` subdomains):

- subdomains ``N = B^2 S^2`` (contact ``2 S^2``), each with ``m = (E+1)^2``
  local dofs; the unassembled space W has ``n_W = N m`` dofs and global dofs
  ``ndof ~ (B S E + 1)^2`` (contact ``2 (S E + 1)^2``);
- everything proportional to W (the subdomain stiffness matrices, 9 nnz per
  row of K^(i), loads, index maps, the jump operator B, the Krylov vectors,
  sparse LU factors of blocks above the dense limit): :data:`BYTES_PER_W_DOF`
  per W dof;
- dense local blocks (``m <= DENSE_LIMIT``, factored by stacked Cholesky, and
  their explicit inverses for many right-hand sides): ``1.5 T 8 m^2`` bytes
  for ``T`` distinct subdomains (templates: 9 per body kind of a structured
  square: corner, edge and interior positions; 2 body kinds for contact, up to
  9 for multibody);
- method ``direct``: the sparse LU of the global K, :data:`BYTES_PER_DIRECT_DOF`
  per global dof;
- the interpreter with numpy, scipy and NGSolve loaded: :data:`BASE_BYTES`.

Calibration (peak RSS by ``/usr/bin/time -v``, ``python -m ddsolve solve``,
one BLAS thread; measured / estimated MB)::

    poisson fetidp  S=8  E=32   ndof 65025    298 / 368
    poisson fetidp  S=16 E=32   ndof 261121   412 / 577
    poisson fetidp  S=32 E=16   ndof 261121   383 / 475
    poisson fetidp  S=4  E=128  ndof 261121   454 / 436
    poisson direct  S=16 E=32   ndof 261121   670 / 710
    multibody f-f   B=8 S=4 E=16 ndof 268324  391 / 478
    contact smalbe  S=16 E=16   ndof 131841   283 / 330
    poisson fetidp  S=128 E=2   ndof 65025    260 / 317   (16384 subdomains, set-up 2.9 s)
    multibody f-f   B=64 S=2 E=2 ndof 101124  303 / 317   (16384 subdomains, set-up 4.2 s)

so the estimate is within about -5 % / +40 % of the peak: a problem is
refused only when it would need clearly more than the machine has.

Unstructured meshes (``mesh: unstructured``) are estimated before netgen runs:
triangles ``T ~ TRIANGLES_PER_AREA * area / maxh^2 * 4^refine`` (area of the
geometry: :data:`GEOMETRY_AREA`; a mesh file: its size in bytes over
:data:`MESH_FILE_BYTES_PER_TRIANGLE`), nodes ``~ T / 2``, subdomains
``parts x bodies``, and :data:`BYTES_PER_UNSTRUCTURED_NODE` per node (netgen and
NGSolve meshes, the broken assembly, W, the batched sparse local factors; no
dense blocks: unstructured subdomains are factored as one sparse block
diagonal) plus :data:`BYTES_PER_UNSTRUCTURED_PART` per subdomain. Calibration (peak RSS by ``/usr/bin/time -v``, poisson fetidp on the
square; measured / estimated MiB)::

    maxh 0.02            parts 16   ndof 2798     169 / 170
    maxh 0.02  refine 2  parts 16   ndof 45953    285 / 294
    maxh 0.01  refine 2  parts 64   ndof 184497   664 / 689
    maxh 0.01  refine 2  parts 256  ndof 184497   578 / 689

Work: set-up loops over subdomains in Python (scene, assembly, local
factorization groups): :data:`SECONDS_PER_SUBDOMAIN` each, plus
:data:`SECONDS_PER_W_DOF` for the vectorised work, plus for a built-in
unstructured geometry netgen's meshing, :data:`SECONDS_PER_MESHED_TRIANGLE` per
triangle before refinement; the estimate is of set-up seconds and is compared
with :data:`MAX_SETUP_SECONDS`.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .errors import InputError, brief

if TYPE_CHECKING:  # pragma: no cover
    from .spec import ProblemSpec

#: Resident memory of the interpreter with numpy, scipy and NGSolve imported (bytes).
BASE_BYTES = 170e6
#: Bytes per dof of the unassembled space W (matrices, vectors, index maps, sparse local LU).
BYTES_PER_W_DOF = 1000.0
#: Bytes per global dof of the sparse direct factorization (method ``direct``).
BYTES_PER_DIRECT_DOF = 1000.0
#: Local blocks up to this size are dense (ddsolve.dd.local.DENSE_LIMIT).
DENSE_LIMIT = 1200
#: Set-up seconds per subdomain (Python loops) and per W dof (vectorised work).
SECONDS_PER_SUBDOMAIN = 2e-4
SECONDS_PER_W_DOF = 2e-6
#: Longest estimated set-up refused without an explicit larger ``max_seconds``.
MAX_SETUP_SECONDS = 3600.0
#: Triangles of a netgen mesh per unit area at maxh = 1 (T ~ 2.3 area / maxh^2, measured on the square).
TRIANGLES_PER_AREA = 2.3
#: Seconds per triangle of netgen's meshing of a built-in geometry (before the uniform refinements, which
#: are cheap): 9,700-12,000 triangles/s on the square, hole and lshape at maxh 0.02 and 0.01 (2026-11-28,
#: one process). Without it a maxh of 0.004 (48 s of meshing under load) was estimated at 0.15 s.
SECONDS_PER_MESHED_TRIANGLE = 1e-4
#: Area of each built-in unstructured geometry (ddsolve.options.GEOMETRIES).
GEOMETRY_AREA = {"square": 1.0, "lshape": 0.75, "hole": 1.0 - math.pi / 16.0, "membranes": 2.0}
#: Bytes of a netgen .vol file per triangle (points and elements as text), for mesh files.
MESH_FILE_BYTES_PER_TRIANGLE = 60.0
#: Peak bytes per node of an unstructured solve (meshes, assembly, W, batched sparse local factors).
BYTES_PER_UNSTRUCTURED_NODE = 3000.0
#: Peak bytes per METIS part of an unstructured solve (per-part index arrays, coarse space, METIS itself);
#: measured 28 kB: maxh 0.005 (46k nodes), 100 / 2,000 / 8,000 parts: 303 / 363 / 524 MB (a review: 10,000 parts
#: used 616 MB against an estimate of 308 MB without this term).
BYTES_PER_UNSTRUCTURED_PART = 32e3
#: Share of the available memory a solve may plan to use.
MEMORY_FRACTION = 0.9


@dataclass(frozen=True)
class Estimate:
    """Estimated size and cost of a solve.

    Attributes
    ----------
    n_subdomains, n_w, ndof : int
        Subdomains, dofs of W, global dofs.
    memory_bytes : float
        Estimated peak resident memory.
    setup_seconds : float
        Estimated set-up time (Python loops over subdomains and vectorised work).
    """

    n_subdomains: int
    n_w: int
    ndof: int
    memory_bytes: float
    setup_seconds: float


def estimate(spec: "ProblemSpec") -> Estimate:
    """The :class:`Estimate` of ``spec`` (see the module docstring for the model)."""
    if getattr(spec, "mesh", "structured") == "unstructured":
        return _estimate_unstructured(spec)
    B, S, E = int(spec.bodies), int(spec.subdomains), int(spec.elements)
    if spec.problem == "contact":
        n_sub, ndof, kinds = 2 * S * S, 2 * (S * E + 1) ** 2, 2
    else:
        n_sub, ndof, kinds = (B * S) ** 2, (B * S * E + 1) ** 2, min(B * B, 9)
    m = (E + 1) ** 2
    n_w = n_sub * m
    memory = BASE_BYTES + BYTES_PER_W_DOF * n_w
    if m <= DENSE_LIMIT:
        memory += 1.5 * min(n_sub, 9 * kinds) * 8.0 * m * m
    if spec.method == "direct":
        memory += BYTES_PER_DIRECT_DOF * ndof
    seconds = SECONDS_PER_SUBDOMAIN * n_sub + SECONDS_PER_W_DOF * n_w
    return Estimate(n_subdomains=n_sub, n_w=n_w, ndof=ndof, memory_bytes=float(memory), setup_seconds=seconds)


def unstructured_triangles(spec: "ProblemSpec") -> float:
    """Estimated triangles of an unstructured spec: 2.3 area / maxh^2 * 4^refine (mesh file: from its size)."""
    if spec.mesh_file:
        try:
            size = os.stat(spec.mesh_file).st_size
        except OSError:
            size = 0
        base = size / MESH_FILE_BYTES_PER_TRIANGLE
        if spec.mesh_file.endswith(".gz"):
            base *= 5.0                       # text compresses about 5:1
    else:
        maxh = float(spec.maxh)     # divided twice: maxh ** 2 underflows to 0 for maxh = 1e-300 (inf, not an error)
        base = TRIANGLES_PER_AREA * GEOMETRY_AREA.get(spec.geometry, 1.0) / maxh / maxh
    return base * 4.0 ** int(spec.refine)


def _estimate_unstructured(spec: "ProblemSpec") -> Estimate:
    triangles = unstructured_triangles(spec)
    nodes = 0.5 * triangles + 1.0
    bodies = 2 if spec.problem == "contact" else (int(spec.bodies) ** 2 if not spec.mesh_file else 1)
    n_sub = int(spec.parts) * bodies
    memory = BASE_BYTES + BYTES_PER_UNSTRUCTURED_NODE * nodes + BYTES_PER_UNSTRUCTURED_PART * n_sub
    if spec.method == "direct":
        memory += BYTES_PER_DIRECT_DOF * nodes
    seconds = SECONDS_PER_SUBDOMAIN * n_sub + SECONDS_PER_W_DOF * nodes
    if not spec.mesh_file:             # netgen meshes the geometry at maxh, then refines uniformly
        seconds += SECONDS_PER_MESHED_TRIANGLE * triangles / 4.0 ** int(spec.refine)
    return Estimate(n_subdomains=n_sub, n_w=int(min(nodes, 1e18)), ndof=int(min(nodes, 1e18)),
                    memory_bytes=float(memory), setup_seconds=seconds)


def estimate_memory(spec: "ProblemSpec") -> float:
    """Estimated peak resident memory of solving ``spec`` (bytes)."""
    return estimate(spec).memory_bytes


def estimate_work(spec: "ProblemSpec") -> float:
    """Estimated set-up seconds of ``spec`` (Python-level loops over subdomains included)."""
    return estimate(spec).setup_seconds


def _read_int(path: str, key: str | None = None) -> int | None:
    try:
        with open(path, encoding="ascii", errors="replace") as fh:
            text = fh.read(1 << 16)
    except OSError:
        return None
    if key is None:
        text = text.strip()
        return int(text) if text.isdigit() else None
    match = re.search(rf"^{key}:\s*(\d+)\s*kB", text, re.MULTILINE)
    return int(match.group(1)) * 1024 if match else None


def available_memory() -> int:
    """Memory this process can use now (bytes).

    ``MemAvailable`` of ``/proc/meminfo`` (else free physical pages from
    ``os.sysconf``), capped by a cgroup v2 ``memory.max`` limit if one is set.
    """
    avail = _read_int("/proc/meminfo", "MemAvailable")
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            avail = 1 << 62
    limit = _read_int("/sys/fs/cgroup/memory.max")
    usage = _read_int("/sys/fs/cgroup/memory.current")
    if limit is not None:
        avail = min(avail, max(limit - (usage or 0), 0))
    return int(avail)


_SIZE = re.compile(r"(?P<num>\d+(?:\.\d*)?|\.\d+)(?:[eE](?P<exp>[+-]?\d+))?\s*(?P<unit>[kmgtp]?)(?P<i>i?)b?",
                   re.IGNORECASE)


def parse_size(value: Any, field: str = "max_memory") -> float:
    """A memory size in bytes: a number of bytes or one with a unit, e.g. ``"500M"``, ``"1.5GiB"``, ``"2e9"``.

    Units K, M, G, T, P are powers of 1024 (with or without ``i`` and ``B``).

    Raises
    ------
    InputError
        ``field``, for anything but a positive finite size.
    """
    if type(value).__module__ == "numpy" and hasattr(value, "item"):
        value = value.item()
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        out = float(value) if not isinstance(value, int) or abs(value) < 1 << 100 else math.inf
    elif isinstance(value, str) and len(value) <= 40 and (match := _SIZE.fullmatch(value.strip())):
        scale = 1024.0 ** "kmgtp".find(match["unit"].lower()) * 1024.0 if match["unit"] else 1.0
        out = float(f"{match['num']}e{match['exp'] or 0}") * scale     # inf, never OverflowError
    else:
        raise InputError(field, f"must be a size in bytes such as 500M or 8G, got {brief(value)}")
    if not math.isfinite(out) or out <= 0:
        raise InputError(field, f"must be a positive size in bytes such as 500M or 8G, got {brief(value)}")
    return out


def _positive(value: Any, field: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError, OverflowError):
        raise InputError(field, f"must be a positive number, got {brief(value)}") from None
    if isinstance(value, bool) or not math.isfinite(out) or out <= 0:
        raise InputError(field, f"must be a positive number, got {brief(value)}")
    return out


def _human(nbytes: float) -> str:
    if not math.isfinite(nbytes):
        return "an unbounded amount"     # the estimate overflowed (maxh = 1e-300)
    for unit, scale in (("TiB", 1024.0 ** 4), ("GiB", 1024.0 ** 3), ("MiB", 1024.0 ** 2)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{nbytes / 1024:.3g} KiB"


def _largest_field(spec: "ProblemSpec", est: Estimate | None = None) -> str:
    """The field a "problem too large" names: the largest size, or for an unstructured mesh whose time
    estimate is mostly its subdomains (a review: ``--parts 1000000000`` was blamed on ``maxh``) the
    larger of ``parts`` and ``bodies`` (bodies^2 of them)."""
    if getattr(spec, "mesh", "structured") == "unstructured":
        if est is not None and SECONDS_PER_SUBDOMAIN * est.n_subdomains > SECONDS_PER_W_DOF * est.n_w:
            bodies = int(spec.bodies) ** 2 if spec.problem == "multibody" and not spec.mesh_file else 1
            return "bodies" if bodies > int(spec.parts) else "parts"
        if spec.mesh_file:
            return "refine" if spec.refine else "mesh_file"
        return "maxh" if spec.refine == 0 else "refine"
    sizes = {"elements": spec.elements, "subdomains": spec.subdomains, "bodies": spec.bodies}
    return max(sizes, key=lambda k: sizes[k])


def _check_parts_per_body(spec: "ProblemSpec") -> None:
    """Refuse, before netgen meshes anything, more ``parts`` than the square bodies of an unstructured
    multibody scene can have elements. netgen gives a square body of side s at least 2 triangles, and
    about max(2, 2.3 s^2 / maxh^2) (measured: 2 for s / maxh <= 1.1, 6 at 1.7 and 2.2, 24 at 3.3); the
    bound used here is 2 below 2.5 triangles by the formula, else twice the formula plus 2. Meshing
    10,000 bodies took 50 s and 540 MB before the partition refused 4 parts of 2 elements (a review)."""
    if (getattr(spec, "mesh", "structured") != "unstructured" or spec.problem != "multibody"
            or spec.mesh_file or int(spec.refine) > 0):
        return
    side = 1.0 / int(spec.bodies)
    formula = TRIANGLES_PER_AREA * side * side / float(spec.maxh) / float(spec.maxh)
    most = 2.0 if formula < 2.5 else 2.0 * formula + 2.0
    if int(spec.parts) > most:
        raise InputError("parts", f"{spec.parts} subdomains requested but each of the {int(spec.bodies) ** 2} "
                                  f"bodies (side {side:.3g}) gets about {max(2.0, formula):.3g} elements at maxh "
                                  f"{float(spec.maxh):g}; use fewer parts or a finer mesh (smaller maxh, more "
                                  f"refine)")


def check_resources(spec: "ProblemSpec", max_memory: Any = None, max_seconds: Any = None) -> Estimate:
    """Refuse ``spec`` if its estimated memory or set-up time exceeds the limits.

    Parameters
    ----------
    spec : ProblemSpec
    max_memory : int, float or str, optional
        Memory limit (bytes or a size such as ``"8G"``, see :func:`parse_size`);
        default :data:`MEMORY_FRACTION` of :func:`available_memory`.
    max_seconds : float, optional
        Set-up time limit; default :data:`MAX_SETUP_SECONDS`.

    Returns
    -------
    Estimate

    Raises
    ------
    InputError
        Naming the largest of ``bodies``, ``subdomains`` and ``elements``, with
        the estimate and the limit (and how to raise it).
    """
    est = estimate(spec)
    _check_parts_per_body(spec)
    if max_memory is None:
        limit, source = MEMORY_FRACTION * available_memory(), "available memory; raise with --max-memory, or max_memory= in Python"
    else:
        limit, source = parse_size(max_memory), "--max-memory / max_memory"
    if est.memory_bytes > limit:
        raise InputError(_largest_field(spec, est),
                         f"problem too large: {'~' if math.isfinite(est.memory_bytes) else ''}{_human(est.memory_bytes)} estimated for {est.n_w:.3g} W dofs, "
                         f"limit {_human(limit)} ({source})")
    seconds = MAX_SETUP_SECONDS if max_seconds is None else _positive(max_seconds, "max_seconds")
    if est.setup_seconds > seconds:
        raise InputError(_largest_field(spec, est),
                         f"problem too large: ~{est.setup_seconds:.3g} s of set-up estimated for "
                         f"{est.n_subdomains:.3g} subdomains, limit {seconds:.3g} s")
    return est


__all__ = ["Estimate", "estimate", "estimate_memory", "estimate_work", "available_memory", "parse_size",
           "check_resources", "BASE_BYTES", "BYTES_PER_W_DOF", "BYTES_PER_DIRECT_DOF", "MAX_SETUP_SECONDS"]
