"""ArduCopter's flight modes (HEARTBEAT ``custom_mode``), by name and number.

The one table is the dialect's ``COPTER_MODE`` enum (ardupilotmega.xml, generated into
:mod:`.tcm_dialect`, so ``tcm_dialect.COPTER_MODE_GUIDED`` is a mode's number): this
module only indexes it by name (``"GUIDED"``, ``"SMART_RTL"``) for people and logs.
"""

from __future__ import annotations

from . import tcm_dialect as dialect

__all__ = ["COPTER_MODES", "mode_name", "mode_number"]

_PREFIX = "COPTER_MODE_"

#: ArduCopter custom_mode numbers by name (ArduCopter/mode.h), e.g. ``"GUIDED"`` -> 4
COPTER_MODES: dict[str, int] = {
    entry.name.removeprefix(_PREFIX): number
    for number, entry in sorted(dialect.enums["COPTER_MODE"].items())
    if entry.name != f"{_PREFIX}ENUM_END"
}
_MODE_NAMES = {number: name for name, number in COPTER_MODES.items()}


def mode_number(mode: str | int) -> int:
    """ArduCopter custom_mode for a name (``"GUIDED"``, any case) or a number."""
    if isinstance(mode, int):
        return mode
    try:
        return COPTER_MODES[mode.upper()]
    except KeyError:
        raise ValueError(f"unknown ArduCopter mode {mode!r}") from None


def mode_name(mode: int) -> str:
    """The name of custom_mode ``mode`` (its number as text when ArduCopter has none)."""
    return _MODE_NAMES.get(mode, str(mode))
