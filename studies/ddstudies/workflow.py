"""Config handling of the Snakemake workflow (``workflows/``): schemas, study kinds, job labels (the
integrity of the study's files, :mod:`ddstudies.integrity`, is re-exported here).

The workflow's JSON schemas (``workflows/schemas/*.schema.yaml``) name the
option lists of :mod:`ddsolve.options` instead of copying them: a schema node
``{x-options: NAME}`` gets ``enum: <the list NAME>`` when the schema is loaded
(:func:`load_schema`), where NAME is an attribute of :mod:`ddsolve.options`,
optionally followed by a key (``METHODS.multibody``). This module imports
neither numpy nor pandas, so that the workflow's DAG is built quickly.
"""
from __future__ import annotations

import copy
import os
from typing import Any, Iterable, Mapping

import yaml

from ddsolve import options

from .integrity import (OWNER_FILE, check_results, quarantine, read_job_results, read_manifest,  # re-exported
                        rebuild_below_missing, record_lock_owner, release_complete, release_stale_lock,
                        remove_stale_tmp, sha256, write_manifest, write_text)

__all__ = ["load_yaml_strict", "check_config_files", "rule_sets", "contact_precision_grids", "KINDS", "SCHEMAS",
           "ConfigError", "load_schema", "validate",
           "unique_labels", "bench_tol_label", "bench_rtols", "check_finite", "check_cases", "case_mem_mb",
           "case_runtime", "machine_memory", "check_results", "quarantine", "remove_stale_tmp", "release_complete",
           "record_lock_owner", "release_stale_lock", "sha256", "write_manifest", "read_manifest", "write_text",
           "canonical_numbers", "read_job_results", "rebuild_below_missing", "OWNER_FILE"]

#: Study kinds (config key ``kind``) and the schema each is validated against.
SCHEMAS: dict[str, str] = {"grid": "config", "table_4": "config", "contact": "config", "bench": "bench",
                           "scaling": "scaling", "stress": "stress", "mpi": "mpi",
                           "ngsolve": "ngsolve", "unstructured": "unstructured"}
#: The study kinds.
KINDS: tuple[str, ...] = tuple(SCHEMAS)


class ConfigError(ValueError):
    """An invalid workflow config; the message names the key: ``<where>: <what>``."""


def _option(name: str) -> list[Any]:
    if name == "SPEC_FIELDS":  # the fields of ddsolve.spec.ProblemSpec
        from ddsolve.spec import ProblemSpec

        return list(ProblemSpec.fields())
    if name == "BENCH_PROBLEMS":   # the problems of the work-precision benchmark (ddstudies.bench.problems)
        from .bench.problems import PROBLEMS

        return list(PROBLEMS)
    if name == "FIT_MODELS":   # the fit models of the figures (ddstudies.report.plots)
        from .report.plots import FIT_MODELS

        return list(FIT_MODELS)
    attr, _, key = name.partition(".")
    value = getattr(options, attr)
    if key:
        value = value[key]
    return list(value)


def inject_options(node: Any) -> Any:
    """Replace every ``{x-options: NAME}`` of a loaded schema by ``enum: <ddsolve.options.NAME>`` (in place)."""
    if isinstance(node, dict):
        name = node.pop("x-options", None)
        if name is not None:
            node["enum"] = _option(name)
        for value in node.values():
            inject_options(value)
    elif isinstance(node, list):
        for value in node:
            inject_options(value)
    return node


class _UniqueKeyLoader(yaml.SafeLoader):
    """yaml.SafeLoader that refuses a mapping with a key given twice (PyYAML keeps the last one, silently)."""


def _unique_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    """The mapping of ``node``, refusing a key written twice. Merge keys (``<<: *anchor``) are left to PyYAML
    (a key of the mapping overrides a merged one, as YAML says); a key that is not a plain scalar (``? [a, b]``)
    is not compared."""
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
            continue
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise ConfigError(f"key {key!r} appears twice in one mapping (lines {seen[key] + 1} and "
                              f"{key_node.start_mark.line + 1}); YAML would keep the last one silently")
        seen[key] = key_node.start_mark.line
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def load_yaml_strict(stream: Any) -> Any:
    """``yaml.safe_load`` that raises :class:`ConfigError` on a key given twice in one mapping (a review: a
    config with ``methods:`` twice ran the second list only, without a word)."""
    return yaml.load(stream, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass


def check_config_files(paths: Iterable[str | os.PathLike]) -> None:
    """Refuse (:class:`ConfigError`, naming the file) a config file with a key given twice; files that are
    missing or not YAML are left to Snakemake's own loading, which reports them."""
    for path in paths:
        try:
            with open(path, encoding="utf-8") as stream:
                load_yaml_strict(stream)
        except ConfigError as err:
            raise ConfigError(f"invalid config: {os.fspath(path)}: {err}") from None
        except (OSError, yaml.YAMLError, UnicodeDecodeError):
            continue


def load_schema(path: str | os.PathLike) -> dict[str, Any]:
    """A workflow schema (YAML) with the option lists of :mod:`ddsolve.options` injected."""
    with open(path) as stream:
        return inject_options(yaml.safe_load(stream))


def _validator_with_defaults():
    from jsonschema import Draft202012Validator, validators

    validate_properties = Draft202012Validator.VALIDATORS["properties"]

    def set_defaults(validator, properties, instance, schema):
        for prop, subschema in properties.items():
            if isinstance(instance, dict) and "default" in subschema:
                instance.setdefault(prop, copy.deepcopy(subschema["default"]))
        yield from validate_properties(validator, properties, instance, schema)

    return validators.extend(Draft202012Validator, {"properties": set_defaults})


_SCALAR_TYPES = {"integer": int, "number": (int, float), "boolean": bool}


def _coerce_strings(data: dict[str, Any], errors) -> bool:
    """Read, in place, the strings that a schema wants as numbers or booleans as YAML; whether any changed.

    Snakemake's ``--config key=[2,3]`` reads the items of a list as strings
    (YAML's base loader); a string is replaced only where the schema's type
    lacks "string" and the YAML value has one of the wanted types, also inside the
    branches of ``oneOf``/``anyOf`` (``bodies=[2,3]`` was refused: a review).
    """
    def leaves(errs):                  # the branches of oneOf/anyOf ($defs "counts": an integer or a list of them)
        for err in errs:
            yield err
            yield from leaves(err.context or ())

    changed = False
    for err in leaves(errors):
        wanted = err.validator_value if err.validator == "type" else None
        wanted = [wanted] if isinstance(wanted, str) else list(wanted or [])
        if not isinstance(err.instance, str) or "string" in wanted or not err.absolute_path:
            continue
        try:
            value = yaml.safe_load(err.instance)
        except yaml.YAMLError:
            continue
        for parse in (int, float):      # YAML 1.1 reads 1e-6 (no dot) as a string
            if isinstance(value, str):
                try:
                    value = parse(value)
                except ValueError:
                    pass
        if not any(isinstance(value, _SCALAR_TYPES[t]) and (t == "boolean" or not isinstance(value, bool))
                   for t in wanted if t in _SCALAR_TYPES):
            continue
        *parents, last = err.absolute_path
        node = data
        for part in parents:
            node = node[part]
        node[last] = value
        changed = True
    return changed


def validate(data: dict[str, Any], schema: str | os.PathLike | Mapping[str, Any], key: str = "config") -> dict:
    """Validate ``data`` against a schema (a path: loaded with :func:`load_schema`), filling in defaults.

    A string where the schema wants a number or a boolean is read as YAML first
    (``--config subdomains=[2,3]``, whose items Snakemake passes as strings).

    Raises
    ------
    ConfigError
        ``invalid <key> (<schema file>): <path>: <what is wrong>``, the most specific error only.
    """
    import jsonschema

    name = os.path.basename(str(schema)) if not isinstance(schema, Mapping) else "schema"
    schema = load_schema(schema) if not isinstance(schema, Mapping) else schema
    errors = list(_validator_with_defaults()(schema).iter_errors(data))
    while errors and _coerce_strings(data, errors):   # --config subdomains=[2,3] gives ['2', '3']
        errors = list(_validator_with_defaults()(schema).iter_errors(data))
    if errors:
        best = jsonschema.exceptions.best_match(errors)  # the most specific error of anyOf / if-then
        where = "/".join(str(part) for part in best.absolute_path) or "(top level)"
        message = _describe(best)
        message = message if len(message) <= 300 else message[:300] + " ..."
        raise ConfigError(f"invalid {key} ({name}): {where}: {message}")
    return data


def _describe(err) -> str:
    """What is wrong, in words that name the key: jsonschema's messages of ``anyOf``/``oneOf``, ``not`` and
    ``minItems`` quote the whole instance instead (a grid config without ``subdomains`` printed the merged
    config, cut off; a review)."""
    if err.validator in ("anyOf", "oneOf") and err.context:
        required = sorted({repr(e.validator_value[0]) if len(e.validator_value) == 1 else
                           " and ".join(map(repr, e.validator_value)) for e in err.context
                           if e.validator == "required" and not e.relative_path})
        if required and isinstance(err.instance, dict):
            return f"needs {' or '.join(required)}"
    if err.validator == "not":
        why = err.schema.get("description") if isinstance(err.schema, dict) else None
        return f"not allowed here{f' ({why})' if why else ''}"
    if err.validator == "minItems":
        if not err.instance:
            return "must not be empty"
        return f"needs at least {err.validator_value} items, got {len(err.instance)}"
    return err.message


def unique_labels(labels: Iterable[tuple[str, Any]], what: str) -> dict[str, Any]:
    """``{label: value}`` of (label, value) pairs, refusing two values with the same label.

    Labels name job outputs; two values sharing one would silently be one job.

    Raises
    ------
    ConfigError
        ``<what>: <v1> and <v2> both have the label <label>``.
    """
    out: dict[str, Any] = {}
    for label, value in labels:
        if label in out:
            raise ConfigError(f"{what}: {out[label]!r} and {value!r} both have the label {label!r}; "
                              f"job labels must be unique (give values that differ in the label)")
        out[label] = value
    return out


def bench_tol_label(rtol: float) -> str:
    """The path label of a benchmark tolerance: ``rtol1e-06`` (one significant digit)."""
    return f"rtol{float(rtol):.0e}"


def bench_rtols(rtols: Iterable[float]) -> dict[str, float]:
    """``{label: rtol}`` of the benchmark tolerances, in config order; duplicates refused.

    >>> bench_rtols([1e-2, 1e-6])
    {'rtol1e-02': 0.01, 'rtol1e-06': 1e-06}
    """
    return unique_labels(((bench_tol_label(r), float(r)) for r in rtols), "rtols")


# --- values the JSON schema cannot express ---------------------------------------------------


def check_finite(data: Any, where: str = "") -> None:
    """Refuse NaN and infinite numbers anywhere in a config (YAML ``.nan``, ``.inf``).

    Raises
    ------
    ConfigError
        ``invalid config: <key path>: must be a finite number, got nan``.
    """
    import math

    if isinstance(data, float) and not math.isfinite(data):
        raise ConfigError(f"invalid config: {where or '(top level)'}: must be a finite number, got {data}")
    if isinstance(data, Mapping):
        for key, value in data.items():
            check_finite(value, f"{where}/{key}" if where else str(key))
    elif isinstance(data, (list, tuple)):
        for index, value in enumerate(data):
            check_finite(value, f"{where}/{index}" if where else str(index))


def canonical_numbers(data: Any) -> Any:
    """Write every integral float of a config as an int, in place (``gamma: 1.0`` -> ``1``); the config.

    YAML reads ``1`` and ``1.0`` as different types, and Snakemake's params
    rerun-trigger compares their ``repr``: without this, writing a value the other
    way would rerun every finished case. Non-integral floats (``rtol: 1.0e-6``)
    and booleans are left as they are.
    """
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list) else ()
    for key, value in list(items):
        if isinstance(value, float) and value.is_integer() and abs(value) < 2.0**53:
            data[key] = int(value)
        else:
            canonical_numbers(value)
    return data


def sorted_keys(data: Any) -> Any:
    """A copy of ``data`` with every mapping's keys in sorted order (lists keep theirs): a params value.

    Snakemake's params rerun-trigger compares their ``repr``, so the same mapping written with its keys
    in another order reran every finished case (a review: a bench config saved with sorted keys reran
    all 15 jobs, "Params have changed").
    """
    if isinstance(data, Mapping):
        return {key: sorted_keys(data[key]) for key in sorted(data, key=str)}
    if isinstance(data, list):
        return [sorted_keys(item) for item in data]
    return data


def machine_memory() -> int:
    """Physical memory of this machine (bytes; ``MemTotal``, capped by a cgroup v2 limit)."""
    total = None
    try:
        with open("/proc/meminfo") as stream:
            for line in stream:
                if line.startswith("MemTotal:"):
                    total = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if total is None:
        try:
            total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            total = 1 << 62
    try:
        with open("/sys/fs/cgroup/memory.max") as stream:
            text = stream.read().strip()
        if text.isdigit():
            total = min(total, int(text))
    except OSError:
        pass
    return int(total)


def _contact_load(spec) -> None:
    """Problem (3.1) has a solution only for loads pressing the membranes together (F <= 0)."""
    from ddsolve.errors import InputError
    from ddsolve.spec import parse_dostal

    if spec.problem != "contact":
        return
    f = spec.f
    if isinstance(f, str) and f.strip().startswith("dostal"):
        loads = parse_dostal(f.strip()[len("dostal"):].lstrip(":"))
    elif isinstance(f, (int, float)):
        loads = (float(f),)
    else:
        return
    if any(v > 0 for v in loads):
        raise InputError("f", f"contact loads must be <= 0 (a positive load pulls the floating membrane "
                              f"off the contact zone: no solution), got {f!r}")
    if not loads[-1] < 0:      # the load on Omega^2 (a constant, or dostal's F2): none presses it (a review)
        raise InputError("f", f"the floating membrane Omega^2 needs a negative load (none presses it onto "
                              f"Omega^1: no unique solution), got {f!r}")


def check_cases(cases: Iterable[tuple[str, Mapping[str, Any]]], max_memory: float | None = None) -> dict:
    """Build every case's :class:`ddsolve.spec.ProblemSpec` and estimate its size, before any job runs.

    Parameters
    ----------
    cases : iterable of (label, mapping)
        The job label of each case (its output path or config key) and its ProblemSpec mapping.
    max_memory : float, optional
        Largest estimated memory of one case (bytes; default :func:`machine_memory`).

    Returns
    -------
    dict
        ``{label: ddsolve.limits.Estimate}``.

    Raises
    ------
    ConfigError
        ``invalid config: case <label>: <field>: <what>`` (the first bad case), or
        ``invalid config: case <label>: needs about <X> of memory, more than <Y> ...``.
    """
    from ddsolve.errors import InputError
    from ddsolve.limits import _human, estimate, parse_size
    from ddsolve.prepared import check_decomposition
    from ddsolve.spec import ProblemSpec

    try:
        limit = parse_size(max_memory) if max_memory else float(machine_memory())
    except InputError as err:
        raise ConfigError(f"invalid config: {err}") from None
    out = {}
    for label, mapping in cases:
        try:
            spec = ProblemSpec.from_mapping(dict(mapping))
            check_decomposition(spec)      # what `ddsolve solve` refuses before building the scene
            _contact_load(spec)
        except InputError as err:
            raise ConfigError(f"invalid config: case {label}: {err}") from None
        size = estimate(spec)
        if size.memory_bytes > limit:
            where = f"max_memory ({_human(limit)})" if max_memory else f"the {_human(limit)} of this machine"
            raise ConfigError(f"invalid config: case {label}: needs about {_human(size.memory_bytes)} of memory, "
                              f"more than {where} (reduce subdomains/elements, or set max_memory)")
        out[label] = size
    return out


def case_mem_mb(size, factor: float = 1.0, floor: int = 500) -> int:
    """The ``mem_mb`` resource of a solve job: ``factor`` x its estimated memory
    (:class:`ddsolve.limits.Estimate`) + 50 %, at least ``floor``."""
    return max(floor, int(1.5 * factor * size.memory_bytes / 2**20) + 1)


def case_runtime(size, factor: float = 1.0, floor: int = 15) -> int:
    """The ``runtime`` resource (minutes) of a solve job: 20 x its estimated set-up time, at least ``floor``."""
    import math

    return max(floor, math.ceil(20.0 * factor * size.setup_seconds / 60.0))


def rule_sets() -> list[str]:
    """The rule sets the fidelity reports sweep: ``"default"``, then every other preset of ddsolve.

    ``ddsolve.options.PRESETS`` (branch ``preset``: ``("default", "thesis")``) when it
    exists; until then only ``["default"]``.
    """
    from ddsolve import options

    presets = [str(p) for p in getattr(options, "PRESETS", ()) if p != "default"]
    return ["default", *presets]


def contact_precision_grids(subdomains: Iterable[int], elements: Iterable[int], limit: int = 32) -> list[str]:
    """``"N,H/h"`` of the study's grids with N * H/h <= ``limit`` (the work-precision comparison's grids)."""
    return [f"{n},{m}" for n in subdomains for m in elements if int(n) * int(m) <= limit]
