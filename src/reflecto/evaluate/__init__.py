"""Validation (paper §6): error metric, baselines, sweeps and figures."""
