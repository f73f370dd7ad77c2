"""The sans-IO science core: pure functions and small classes over numpy arrays.

Nothing in this package reads a clock, a socket, a serial port, a camera or a file;
time is always an argument. Flight, SITL and replay run the very same code.
"""
