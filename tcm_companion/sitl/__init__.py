"""SITL: the daemon flown against a simulated vehicle, scored against the simulator's truth.

- :mod:`.mock_flight` — a flight with the mock autopilot, in real time or on the virtual clock
  (``tcm-companion sitl``, ``run`` with ``[camera] source = "sim"``), and the report.
- :mod:`.virtual` — the virtual-time driver: mock, camera and companion on one simulated
  clock (``sitl --clock virtual``).
- :mod:`.ardupilot` — with real ArduCopter SITL and the Lua applet
  (``sitl --autopilot ardupilot``).
- real ArduCopter SITL itself: :mod:`.ardupilot_process` (the binary, its instance and
  process), :mod:`.gcs` (the ground-station client: :mod:`tcm_companion.mavlink.gcs` on a
  transport), :mod:`.ardupilot_vehicle` (booting and flying it), :mod:`.errors`.
"""
