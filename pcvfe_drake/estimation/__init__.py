"""Estimation: fit datasets, the friction fitter, the per-context estimator, synthetic drives."""
