"""garage_exp: perception experiments in simulated underground parking garages."""

__version__ = "0.1.0"
