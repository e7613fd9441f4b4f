"""simulate: physically based fiber and fabric BRDFs (Mie, Monte Carlo transport, Cook-Torrance)."""

from gonio.version import VERSION as __version__

__all__ = ["__version__"]
