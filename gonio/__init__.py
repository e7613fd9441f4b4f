"""gonio: goniophotometer driver, mock devices, acquisition, and the radiance-coefficient dataset.

`gonio.data` is the one place that reads and writes radiance-coefficient datasets;
`gonio.data.colour` derives CIE XYZ / linear sRGB / HSV views of their spectra.
"""

from gonio.version import VERSION as __version__

__all__ = ["__version__"]
