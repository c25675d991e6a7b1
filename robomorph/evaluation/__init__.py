"""Evaluation: metrics, FIT bands, baselines, physics baselines, plots, tables, evaluate()."""
