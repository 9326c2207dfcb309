"""One solve per HDF5 file: write atomically, read back as a flat dictionary.

The file layout (``format = "ddsolve-result"``, ``format_version = 1``) is
documented in one place only: ``docs/hdf5.md``.
In short: root attributes ``format``, ``format_version``, ``ddsolve_version``;
group ``/params`` with one attribute per :class:`~ddsolve.spec.ProblemSpec`
field; group ``/result`` with one attribute per scalar of
:meth:`~ddsolve.result.SolveResult.to_dict` (``None`` stored as NaN; the
dictionary ``timings`` flattened to ``timings_mesh``, ``timings_partition``,
... attributes), the dataset ``/result/residuals`` and one dataset per
list-valued entry.

:func:`write_result` never leaves a partial file at the target path: it builds
the file in memory (h5py's ``core`` driver without backing store), writes the
image with plain Python file I/O to ``.<name>.<pid>.<random>.tmp`` in the
target's directory, flushes and fsyncs it, then renames it onto the target with
:func:`os.replace` (atomic on POSIX); on any error the temporary file is removed
and the target is left untouched. libhdf5 itself never writes to the disk, so a
full disk is an ordinary ``OSError`` of the byte write, not a failure (or a
crash) inside the HDF5 library.
A full disk (``ENOSPC``, ``EDQUOT``) is reported as one line,
:class:`NoSpaceError` ``no space left on device writing <path>``.

Every reader checks the file it opens: a missing, truncated or corrupt file
raises :class:`ResultFileError` naming the path (never a bare h5py error).
:func:`validate_result` reads a whole file and returns the same error;
:func:`quick_check` is the cheap, numpy-free test (HDF5 signature and the
superblock's end-of-file address against the file size) that the workflow runs
on every existing result before it plans the jobs (``docs/studies.md``,
"Integrity of results").

Fault injection (tests only): with the environment variable
``DDSOLVE_FAULT_ENOSPC`` set to a substring of a target path, :func:`atomic_target`
raises ``OSError(ENOSPC)`` for that target after the temporary file was created,
as a full disk would.
"""
from __future__ import annotations

import errno
import math
import os
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Mapping

import h5py
import numpy as np

from .check import quick_check
from .cleanup import removed_on_termination, replace_onto, resolved_target

__all__ = ["FORMAT", "FORMAT_VERSION", "ResultFileError", "NoSpaceError", "write_result", "atomic_target",
           "read_params", "read_result", "read_residuals", "read_solution", "validate_result", "quick_check",
           "is_missing", "FAULT_ENOSPC_ENV", "TMP_SUFFIX"]

FORMAT = "ddsolve-result"
FORMAT_VERSION = 1

#: Keys that are both spec fields and result scalars and must agree (the
#: identity of the case). Any other name present in both ``/params`` and
#: ``/result`` (today only ``cond``: the flag vs. the estimate) appears in the
#: flat dictionary of :func:`read_result` as ``param_<name>`` for the parameter.
IDENTITY_KEYS: tuple[str, ...] = ("problem", "method", "bodies", "subdomains", "elements", "mesh")
#: Identity keys whose result value is not the parameter's on unstructured meshes: the result
#: reports (parts, 0) for (subdomains, elements), the spec keeps the unused defaults (and with a
#: ``mesh_file`` the result's ``bodies`` are the file's, not checked either).
UNSTRUCTURED_SIZES: tuple[str, ...] = ("subdomains", "elements")
#: Result entries that are dictionaries of scalars, stored flattened as ``<key>_<name>`` attributes.
FLATTENED: tuple[str, ...] = ("timings",)

#: Datasets of ``/result`` that are not list-valued result entries.
RESERVED_DATASETS: tuple[str, ...] = ("residuals", "u")

#: Environment variable of the ENOSPC fault injection (a substring of the target paths to fail).
FAULT_ENOSPC_ENV = "DDSOLVE_FAULT_ENOSPC"
#: Suffix of the temporary files of :func:`atomic_target` (``.<name>.<pid>.<random>.tmp``).
TMP_SUFFIX = ".tmp"
#: Errors of a full disk or an exhausted quota.
NO_SPACE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


class ResultFileError(ValueError):
    """A result file that cannot be read: missing, truncated, corrupt or of another format.

    The message is one line that starts with the path: ``<path>: <what is wrong>``.
    """

    def __init__(self, path: str | os.PathLike, what: str):
        self.path = os.fspath(path)
        self.what = " ".join(str(what).split())
        super().__init__(f"{self.path}: {self.what}")


class NoSpaceError(OSError):
    """A write that failed for a full disk (or quota): ``no space left on device writing <path>``."""

    def __init__(self, path: str | os.PathLike, errnum: int = errno.ENOSPC):
        self.path = os.fspath(path)
        super().__init__(errnum, f"no space left on device writing {self.path}")

    def __str__(self) -> str:  # one line, without OSError's "[Errno 28]" prefix
        return self.strerror


def ddsolve_version() -> str:
    """The installed ddsolve version (``"unknown"`` when it cannot be found)."""
    try:
        import ddsolve

        version = getattr(ddsolve, "__version__", None)
        if version:
            return str(version)
    except ImportError:  # pragma: no cover - we are inside ddsolve
        pass
    try:
        from importlib.metadata import PackageNotFoundError, version as _version

        return _version("ddsolve")
    except PackageNotFoundError:
        return "unknown"


# ----------------------------------------------------------------------------
# conversion helpers
# ----------------------------------------------------------------------------

def _scalar_attr(key: str, value: Any) -> Any:
    """Convert one scalar to an HDF5 attribute value (None -> NaN)."""
    if value is None:
        return np.float64(np.nan)
    if isinstance(value, (bool, np.bool_)):
        return np.bool_(value)
    if isinstance(value, (int, np.integer)):
        if not -2**63 <= int(value) < 2**63:
            raise TypeError(f"{key}: cannot store {value!r} as an HDF5 attribute (outside int64)")
        return np.int64(value)
    if isinstance(value, (float, np.floating)):
        return np.float64(value)
    if isinstance(value, str):
        return value
    raise TypeError(f"{key}: cannot store {type(value).__name__} {value!r} as an HDF5 attribute")


def _list_array(key: str, value: Any) -> np.ndarray:
    """Convert a list-valued entry to an array (ints -> int64, floats/None -> float64)."""
    items = list(value)
    if any(isinstance(v, str) for v in items):
        if not all(isinstance(v, str) for v in items):
            raise TypeError(f"{key}: list mixes strings and other values")
        return np.array(items, dtype=h5py.string_dtype())
    try:
        if any(v is None for v in items):
            return np.array([np.nan if v is None else v for v in items], dtype=np.float64)
        arr = np.asarray(items)
    except (ValueError, TypeError) as exc:
        raise TypeError(f"{key}: cannot store list as a rectangular numeric dataset ({exc})") from None
    if arr.size == 0:
        return np.zeros(arr.shape, dtype=np.int64)
    if arr.dtype == np.bool_:
        return arr
    if np.issubdtype(arr.dtype, np.integer):
        return arr.astype(np.int64)
    if np.issubdtype(arr.dtype, np.floating):
        return arr.astype(np.float64)
    raise TypeError(f"{key}: cannot store list of {arr.dtype} as a dataset")


def _from_attr(value: Any) -> Any:
    """Convert an attribute read by h5py back to a Python scalar."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.ndarray) and value.shape == ():
        return _from_attr(value[()])
    return value


def _from_dataset(ds: h5py.Dataset) -> list:
    if h5py.check_string_dtype(ds.dtype) is not None:
        return ds.asstr()[()].tolist()
    return ds[()].tolist()


def _spec_dict(spec: Any) -> dict[str, Any]:
    if hasattr(spec, "to_dict"):
        return dict(spec.to_dict())
    if isinstance(spec, Mapping):
        return dict(spec)
    raise TypeError(f"spec must be a ProblemSpec or a mapping, got {type(spec).__name__}")


# ----------------------------------------------------------------------------
# writing
# ----------------------------------------------------------------------------

def write_result(path: str | os.PathLike, spec: Any, result: Any, *, store_solution: bool = False) -> Path:
    """Write one run (spec and result) to ``path`` atomically.

    Parameters
    ----------
    path : path-like
        Target ``.h5`` file; its directory is created if needed. An existing
        file is replaced.
    spec : ProblemSpec or mapping
        The problem specification (``spec.to_dict()`` is stored in ``/params``).
    result : SolveResult
        The result: ``result.to_dict()`` (scalars and lists) and
        ``result.residuals`` are stored in ``/result``.
    store_solution : bool
        Also store ``result.u`` as the dataset ``/result/u`` (off by default).

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    ValueError
        If spec and result disagree on an identity key (:data:`IDENTITY_KEYS`: problem, method,
        bodies, subdomains, elements, mesh; see :data:`UNSTRUCTURED_SIZES` for the exceptions).
    TypeError
        If a value cannot be stored (e.g. a dictionary or a ragged list).
    """
    path = Path(path)
    params = _spec_dict(spec)
    summary = dict(result.to_dict())
    for name in FLATTENED:                       # {"timings": {"mesh": s}} -> "timings_mesh": s
        if isinstance(summary.get(name), Mapping):
            summary.update({f"{name}_{k}": v for k, v in summary.pop(name).items()})
    skip = UNSTRUCTURED_SIZES if params.get("mesh") == "unstructured" else ()
    if params.get("mesh_file"):              # the file's bodies (its materials), not the spec's default 1
        skip = (*skip, "bodies")
    for key in IDENTITY_KEYS:
        if key in skip:
            continue
        if key in params and key in summary and params[key] != summary[key]:
            raise ValueError(f"{key}: spec says {params[key]!r} but the result says {summary[key]!r}")

    # Convert everything before touching the disk, so type errors create no file.
    param_attrs = {key: _scalar_attr(f"params/{key}", val) for key, val in params.items()}
    result_attrs: dict[str, Any] = {}
    result_lists: dict[str, np.ndarray] = {}
    for key, val in summary.items():
        if key in RESERVED_DATASETS:
            raise ValueError(f"{key}: result key clashes with a reserved dataset name")
        if isinstance(val, (list, tuple, np.ndarray)):
            result_lists[key] = _list_array(f"result/{key}", val)
        else:
            result_attrs[key] = _scalar_attr(f"result/{key}", val)
    residuals = np.asarray(getattr(result, "residuals", np.zeros(0)), dtype=np.float64).ravel()
    solution = None
    if store_solution and getattr(result, "u", None) is not None:
        solution = np.asarray(result.u)

    # Build the file in memory (HDF5 "core" driver, no backing store) and write its bytes with plain
    # file I/O: a full disk is then an ordinary OSError of os.write, never an error inside libhdf5
    # (which could crash the process instead of reporting it).
    with h5py.File(f"ddsolve-result-{uuid.uuid4().hex}.h5", "w", driver="core", backing_store=False,
                   track_order=True) as h5:
        h5.attrs["format"] = FORMAT
        h5.attrs["format_version"] = np.int64(FORMAT_VERSION)
        h5.attrs["ddsolve_version"] = ddsolve_version()
        gparams = h5.create_group("params", track_order=True)
        for key, val in param_attrs.items():
            gparams.attrs[key] = val
        gresult = h5.create_group("result", track_order=True)
        for key, val in result_attrs.items():
            gresult.attrs[key] = val
        gresult.create_dataset("residuals", data=residuals, dtype=np.float64)
        for key, arr in result_lists.items():
            gresult.create_dataset(key, data=arr)
        if solution is not None:
            gresult.create_dataset("u", data=solution)
        h5.flush()
        image = h5.id.get_file_image()
    with atomic_target(path) as tmp:
        _write_bytes(tmp, image)
    return path


def _write_bytes(path: Path, data: bytes) -> None:
    """Create ``path`` (exclusively) with ``data``, flushed and fsynced; OSError as the OS reports it."""
    with open(path, "xb") as fh:
        view = memoryview(data)
        while view:                                  # os.write may write less than asked
            view = view[fh.write(view):]
        fh.flush()
        os.fsync(fh.fileno())


def _no_space(exc: BaseException) -> bool:
    """True for an error caused by a full disk (also when h5py wraps the OSError)."""
    seen = 0
    while exc is not None and seen < 8:
        if isinstance(exc, OSError) and exc.errno in NO_SPACE_ERRNOS:
            return True
        if "No space left on device" in str(exc) or "Disk quota exceeded" in str(exc):
            return True
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return False


def _inject_enospc(path: Path) -> None:
    """The test hook: fail like a full disk when ``$DDSOLVE_FAULT_ENOSPC`` is a substring of ``path``."""
    marker = os.environ.get(FAULT_ENOSPC_ENV)
    if marker and marker in os.fspath(path):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), os.fspath(path))


@contextmanager
def atomic_target(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success, delete it on error.

    An interrupted writer therefore never leaves a partial file under the final
    name, and a failed or terminated (SIGTERM, SIGHUP) one no temporary file
    (:func:`~ddsolve.io.cleanup.removed_on_termination`; a SIGKILLed one may: the
    workflow removes those when it starts, ``ddstudies.integrity.remove_stale_tmp``).

    Raises
    ------
    NoSpaceError
        For a full disk: ``no space left on device writing <path>`` (the
        original error is its ``__cause__``).
    """
    path = resolved_target(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        if exc.errno in NO_SPACE_ERRNOS:
            raise NoSpaceError(path, exc.errno) from exc
        raise
    # a name of up to 255 bytes is legal; the temporary one adds about 30 characters, so keep its stem short
    tmp = path.with_name(f".{path.name[:200]}.{os.getpid()}.{uuid.uuid4().hex[:8]}{TMP_SUFFIX}")
    try:
        with removed_on_termination(tmp):      # SIGTERM/SIGHUP: no temporary file left either
            yield tmp
            _inject_enospc(path)
            replace_onto(tmp, path)
    except BaseException as exc:
        if isinstance(exc, Exception) and not isinstance(exc, NoSpaceError) and _no_space(exc):
            raise NoSpaceError(path) from exc
        raise
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


# ----------------------------------------------------------------------------
# reading
# ----------------------------------------------------------------------------

def _open_checked(path: str | os.PathLike) -> h5py.File:
    """Open a result file for reading; :class:`ResultFileError` naming the path if that fails."""
    if not os.path.isfile(path):
        raise ResultFileError(path, "no such result file" if not os.path.exists(path) else "not a regular file")
    problem = quick_check(path)
    if problem:
        raise ResultFileError(path, problem)
    try:
        h5 = h5py.File(path, "r")
    except (OSError, ValueError, RuntimeError, KeyError) as exc:
        raise ResultFileError(path, f"cannot open as HDF5 ({_short(exc)})") from exc
    try:
        fmt = _from_attr(h5.attrs.get("format"))
    except (OSError, ValueError, RuntimeError, KeyError) as exc:
        h5.close()
        raise ResultFileError(path, f"corrupt HDF5 file ({_short(exc)})") from exc
    version = _from_attr(h5.attrs.get("format_version"))
    if fmt != FORMAT:
        h5.close()
        raise ResultFileError(path, f"not a ddsolve result file (format={fmt!r})")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        h5.close()
        raise ResultFileError(path, f"unsupported format_version {version!r} "
                                    f"(this ddsolve reads <= {FORMAT_VERSION})")
    return h5


_READ_ERRORS = (OSError, ValueError, RuntimeError, KeyError, TypeError)


def _short(exc: BaseException) -> str:
    """One line of an h5py error (h5py's messages can span lines)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."


@contextmanager
def _opened(path: str | os.PathLike) -> Iterator[h5py.File]:
    """An open, format-checked result file; any read error becomes :class:`ResultFileError` naming ``path``."""
    h5 = _open_checked(path)
    try:
        yield h5
    except ResultFileError:
        raise
    except _READ_ERRORS as exc:
        raise ResultFileError(path, f"corrupt result file ({_short(exc)})") from exc
    finally:
        h5.close()


def read_params(path: str | os.PathLike) -> dict[str, Any]:
    """The ``/params`` group as a dictionary (spec field -> value).

    Raises
    ------
    ResultFileError
        ``<path>: <what is wrong>`` for a missing, truncated or corrupt file.
    """
    with _opened(path) as h5:
        return {key: _from_attr(val) for key, val in h5["params"].attrs.items()}


def read_result(path: str | os.PathLike) -> dict[str, Any]:
    """Read one run as a flat dictionary of parameters and scalar results.

    Returns
    -------
    dict
        The ``/params`` attributes, then the ``/result`` attributes and the
        list-valued ``/result`` datasets (as Python lists; ``residuals`` and
        ``u`` are not included, see :func:`read_residuals`). Missing floats are
        NaN. A parameter whose name is also a result key is overridden by the
        result; unless it is one of :data:`IDENTITY_KEYS` it is kept as
        ``param_<name>`` (e.g. ``param_cond``, the flag, beside ``cond``, the
        estimate).

    Raises
    ------
    ResultFileError
        ``<path>: <what is wrong>`` for a missing, truncated or corrupt file.
    """
    with _opened(path) as h5:
        params = {key: _from_attr(val) for key, val in h5["params"].attrs.items()}
        gresult = h5["result"]
        results = {key: _from_attr(val) for key, val in gresult.attrs.items()}
        for key, obj in gresult.items():
            if key in RESERVED_DATASETS or not isinstance(obj, h5py.Dataset):
                continue
            results[key] = _from_dataset(obj)
    flat: dict[str, Any] = {}
    for key, val in params.items():
        if key in results and key not in IDENTITY_KEYS:
            flat[f"param_{key}"] = val
        else:
            flat[key] = val
    flat.update(results)
    return flat


def read_residuals(path: str | os.PathLike) -> np.ndarray:
    """The residual history ``/result/residuals`` (float64, shape (iterations + 1,))."""
    with _opened(path) as h5:
        return np.asarray(h5["result/residuals"][()], dtype=np.float64)


def read_solution(path: str | os.PathLike) -> np.ndarray | None:
    """The solution ``/result/u`` if it was stored (``store_solution=True``), else None."""
    with _opened(path) as h5:
        if "u" not in h5["result"]:
            return None
        return np.asarray(h5["result/u"][()])


def validate_result(path: str | os.PathLike) -> dict[str, Any]:
    """Check that ``path`` is a complete, readable result file: read every attribute and dataset.

    Returns
    -------
    dict
        :func:`read_result` of the file.

    Raises
    ------
    ResultFileError
        ``<path>: <what is wrong>``: missing, truncated (:func:`quick_check`),
        not HDF5, another format, a missing ``/params`` or ``/result`` group, or
        a dataset that cannot be read.
    """
    flat = read_result(path)
    with _opened(path) as h5:
        for name in ("params", "result"):
            if not isinstance(h5.get(name), h5py.Group):
                raise ResultFileError(path, f"no /{name} group")
        if "residuals" not in h5["result"]:
            raise ResultFileError(path, "no /result/residuals dataset")
        for obj in h5["result"].values():
            if isinstance(obj, h5py.Dataset):
                obj[()]
    return flat


def is_missing(value: Any) -> bool:
    """True for values stored as missing (None written as NaN)."""
    return value is None or (isinstance(value, float) and math.isnan(value))
