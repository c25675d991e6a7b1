"""Tuning: Optuna studies over fit(), search spaces, summaries."""
