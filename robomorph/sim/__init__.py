"""Simulated robot domains: MJCF models, randomization, signals, controllers, rollouts."""
