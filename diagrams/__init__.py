"""Diagram factories and Meshcat wiring (installed as ``pcvfe_drake.diagrams``)."""
