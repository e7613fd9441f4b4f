"""simulate: physically based fiber and fabric BRDFs (Mie, Monte Carlo transport, Cook-Torrance)."""

__version__ = "0.1.0"
