"""Config handling of the Snakemake workflow (``workflows/``): schemas, study kinds, job labels.

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

__all__ = ["rule_sets", "contact_precision_grids", "KINDS", "SCHEMAS", "ConfigError", "load_schema", "validate", "unique_labels", "bench_tol_label",
           "bench_rtols"]

#: Study kinds (config key ``kind``) and the schema each is validated against.
SCHEMAS: dict[str, str] = {"grid": "config", "table_4": "config", "contact": "config", "bench": "bench",
                           "scaling": "scaling", "stress": "stress", "mpi": "mpi",
                           "ngsolve": "ngsolve", "unstructured": "unstructured"}
#: The study kinds.
KINDS: tuple[str, ...] = tuple(SCHEMAS)


class ConfigError(ValueError):
    """An invalid workflow config; the message names the key: ``<where>: <what>``."""


def _option(name: str) -> list[Any]:
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


def validate(data: dict[str, Any], schema: str | os.PathLike | Mapping[str, Any], key: str = "config") -> dict:
    """Validate ``data`` against a schema (a path: loaded with :func:`load_schema`), filling in defaults.

    Raises
    ------
    ConfigError
        ``invalid <key> (<schema file>): <path>: <what is wrong>``, the most specific error only.
    """
    import jsonschema

    name = os.path.basename(str(schema)) if not isinstance(schema, Mapping) else "schema"
    schema = load_schema(schema) if not isinstance(schema, Mapping) else schema
    errors = list(_validator_with_defaults()(schema).iter_errors(data))
    if errors:
        best = jsonschema.exceptions.best_match(errors)  # the most specific error of anyOf / if-then
        where = "/".join(str(part) for part in best.absolute_path) or "(top level)"
        message = best.message if len(best.message) <= 300 else best.message[:300] + " ..."
        raise ConfigError(f"invalid {key} ({name}): {where}: {message}")
    return data


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
