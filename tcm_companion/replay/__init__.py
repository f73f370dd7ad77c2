"""Replay: recorded or simulated inputs through the daemon's code again.

- :mod:`.scenario` — a ``tcm-scenario/1`` directory or a simulated scenario through the
  pipeline, telemetry delivered causally (``tcm-companion replay SCENARIO``, eval).
- :mod:`.log` — process replay of a flight log through a fresh Companion and endpoint
  (``tcm-companion replay LOG``).
"""
