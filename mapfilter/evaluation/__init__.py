"""Evaluation: baselines, every method on the same walks, error metrics and plots."""
