"""gonio: goniophotometer driver, mock devices, acquisition, and the radiance-coefficient dataset.

`gonio.data` is the one place that reads and writes radiance-coefficient datasets;
`gonio.data.colour` derives CIE XYZ / linear sRGB / HSV views of their spectra.
"""

__version__ = "0.1.0"
