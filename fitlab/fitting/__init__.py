"""Fitting: bounded parameter spaces, losses, least squares with global starts, MCMC."""
