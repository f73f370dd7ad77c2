"""tcm-companion: tells the flight controller whether each object the cameras see is
moving or stationary (Triangle Closure Method) and how soon it would hit."""

__version__ = "0.1.0"
