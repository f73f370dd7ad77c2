"""What the simulated camera sees: the field, its objects, the renderer, the scenarios and
their export, truth, the simulated detector, and the simulated camera sources."""
