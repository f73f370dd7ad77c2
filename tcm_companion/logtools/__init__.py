"""Tools for flight logs: conversion to and from scenarios, and analysis plots.

- :func:`log_to_scenario` / :func:`scenario_to_log` (``tcm-companion export`` / ``import``)
- :func:`plot_log` / :func:`plot_scenario` (``tcm-companion plot``)
"""

from __future__ import annotations

from .convert import (
    ExportSummary,
    ImportSummary,
    LogConversionError,
    log_to_scenario,
    scenario_to_log,
)
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
