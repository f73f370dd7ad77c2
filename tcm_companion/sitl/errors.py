"""What the ArduPilot SITL drivers raise (:mod:`.ardupilot_process`, :mod:`.gcs`,
:mod:`.ardupilot_vehicle`)."""

from __future__ import annotations

__all__ = ["SitlError", "SitlTimeout"]


class SitlError(RuntimeError):
    """The SITL did not start, or refused or ignored a request."""


class SitlTimeout(SitlError, TimeoutError):
    """A wait ran out of time."""
