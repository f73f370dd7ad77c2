"""Tools for flight logs: conversion to and from scenarios, and analysis plots.

- :func:`log_to_scenario` / :func:`scenario_to_log` (``tcm-companion export`` / ``import``)
- :func:`plot_log` / :func:`plot_scenario` (``tcm-companion plot``)

The plots need matplotlib, of the ``tools`` extra, which the drone's install leaves out:
they are imported when first asked for (``from tcm_companion.logtools import plot_log``
or :mod:`.plot`), so that ``export`` and ``import`` work without it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .convert import (
    ExportSummary,
    ImportSummary,
    LogConversionError,
    log_to_scenario,
    scenario_to_log,
)

if TYPE_CHECKING:
    from .plot import PlotFiles, plot_log, plot_scenario

__all__ = [
    "ExportSummary",
    "ImportSummary",
    "LogConversionError",
    "PlotFiles",
    "log_to_scenario",
    "plot_log",
    "plot_scenario",
    "scenario_to_log",
]

_PLOTS = ("PlotFiles", "plot_log", "plot_scenario")


def __getattr__(name: str) -> Any:
    """The plotting names, imported (with matplotlib) on first use."""
    if name in _PLOTS:
        from . import plot

        return getattr(plot, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
