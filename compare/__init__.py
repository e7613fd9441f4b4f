"""compare: normalise simulations to a measurement, curve errors, HSV colour match, reports."""

__version__ = "0.1.0"
