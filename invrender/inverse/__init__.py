"""Inverse rendering: gradient estimators, losses, fitting, gradient checks."""
