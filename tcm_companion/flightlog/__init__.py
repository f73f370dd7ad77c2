"""The flight log: MCAP files of every frame, MAVLink byte, result and health record.

- :mod:`.writer` — the :class:`~.writer.FlightLogWriter` (its own thread, bounded queue,
  rotation, disk floor), with one module per job beside it: :mod:`.settings`
  (:class:`~.settings.LoggingConfig`, ``[logging]``), :mod:`.stats` (its counts,
  :class:`~.stats.FlightLogStats`, and state), :mod:`.encoding` (items as MCAP messages),
  :mod:`.part` (one MCAP file of the log) and :mod:`.disk` (free space, flushing a part
  to the OS).
- :mod:`.handle` — :class:`~.handle.FlightLog`, what the companion host writes through
  (live or deterministic).
- :mod:`.reader` — reading logs back (also after a crash).
- :mod:`.topics` — the table of topics every writer and reader names.
- :mod:`.docs` — the per-frame result documents the daemon logs.

Opening a run's log from the configuration is the application's
(:mod:`tcm_companion.flight_log_setup`). The submodules are imported on their own; this package
imports nothing, so that :mod:`.topics` does not pull in MCAP.
"""
