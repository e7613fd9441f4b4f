"""gonio: goniophotometer driver, mock devices, acquisition, and the radiance-coefficient dataset.

`gonio.dataset` is the one place that reads and writes radiance-coefficient datasets;
`gonio.colour` derives CIE XYZ / linear sRGB / HSV views of their spectra.
"""

__version__ = "0.1.0"
