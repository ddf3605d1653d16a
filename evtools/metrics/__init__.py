"""Measurements: denoising (labelled and unlabelled), threshold estimation error, edge uniformity."""
