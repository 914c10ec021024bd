"""RAPIDDS: adaptive human-robot team planning."""
__version__ = "0.1.0"
