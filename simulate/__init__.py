"""simulate: physically based fiber and fabric BRDFs (Mie, Monte Carlo transport, Cook-Torrance).

Importing it makes numba cache the package's compiled kernels once per machine, keyed by their
source's content (:mod:`simulate.kernelcache`; numba itself is imported only when a kernel is needed).
"""

from gonio.version import VERSION as __version__
from simulate import kernelcache as _kernelcache

__all__ = ["__version__"]

_kernelcache.install()
