"""Edges: files, transports and devices around the pure core."""
