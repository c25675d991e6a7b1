"""Reporting: the static HTML dashboard over runs and their evaluations."""
