"""What flies the simulated field: synthetic telemetry, the mock autopilot (and the
ArduPilot applet inside it) and real ArduCopter SITL."""
