"""Report rendering: thesis-style tables and plots from aggregated results.

- :mod:`ddstudies.report.tables`: :func:`condition_table`, :func:`side_by_side`,
  :func:`to_markdown`, :func:`to_latex`.
- :mod:`ddstudies.report.plots`: :func:`fit_log_squared`, :func:`fit_linear`,
  :func:`plot_cond_vs_Hh` (matplotlib, Agg backend).

Names are imported lazily so that importing the tables does not load matplotlib.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "condition_table": "tables",
    "side_by_side": "tables",
    "to_markdown": "tables",
    "to_latex": "tables",
    "fit_log_squared": "plots",
    "fit_linear": "plots",
    "plot_cond_vs_Hh": "plots",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        module = importlib.import_module(f".{_EXPORTS[name]}", __name__)
        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
