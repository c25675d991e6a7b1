"""Simulation: the Panda domain, randomization, signals, OSC, engines, filters, episodes, recipes, generation."""
