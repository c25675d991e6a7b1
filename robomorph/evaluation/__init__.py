"""Evaluation: metrics, FIT bands, baselines, physics baselines, plots, tables, evaluate(), and the
hybrid's predictions over a store's windows written as prior stores (``priors``), and the industrial
robot benchmark's published readings (``benchmark_readings``)."""
