"""Simulation: the arms registry and its MJCF domains, randomization, signals, the operational-space
controller and its paths, open- and closed-loop engines, validity filters, episodes and recipes."""
