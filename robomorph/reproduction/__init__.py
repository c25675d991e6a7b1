"""Reproduction of the paper: the pipeline, scales, skip-what-is-done logic, tables, figures."""
