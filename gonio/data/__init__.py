"""The data layer: the one place that reads and writes radiance-coefficient datasets.

One concept per module (``compare`` and ``simulate`` import only from here):

``gonio.data.schema``
    the format's constants (columns, names, limits) and :class:`DatasetError`: the leaf every
    other module imports, importing none of them;
``gonio.data.dataset``
    the dataset format (spectral or RGB, absolute or relative): the `Dataset`, reading and writing;
``gonio.data.validation``
    the checks of a dataset's table, metadata and files that reading and writing share;
``gonio.data.atomic``
    the atomic writers of every output (one file, or several together);
``gonio.data.geometry``
    the fabric frame's conventions: directions, the signed in-plane angle, the instrument's axes
    and the beam-block test shared by plans, datasets and the mock;
``gonio.data.interpolate``
    interpolation of a dataset at geometries and wavelengths inside its data;
``gonio.data.colour``
    CIE XYZ / linear RGB / HSV views of spectra and of RGB channels (colour-science);
``gonio.data.formats``
    importers of other formats: RGL ``.bsdf`` (Dupuy & Jakob 2018), pgII text, MERL binary;
``gonio.data.outputs``
    the one rule of what a command that writes may replace (run folders never).
"""

from gonio.data.colour import ColourSummary, display_srgb, hue_difference, rgb_colour, spectrum_colour, spectrum_to_rgb
from gonio.data.dataset import (
    CHANNELS,
    COLUMNS,
    CSV_NAME,
    DEFAULT_COLOUR_SPACE,
    GEOMETRY,
    META_NAME,
    RGB_COLUMNS,
    SCHEMA,
    Dataset,
    DatasetError,
    atomic_write,
    make_dataset,
    new_meta,
    read_dataset,
    remove_stale_temp_files,
    write_dataset,
    write_files_together,
)
from gonio.data.geometry import beam_blocked, direction, in_plane_geometry, signed_angle, spherical_angles
from gonio.data.interpolate import interpolate

__all__ = [
    "CHANNELS", "COLUMNS", "CSV_NAME", "DEFAULT_COLOUR_SPACE", "GEOMETRY", "META_NAME",
    "RGB_COLUMNS", "SCHEMA", "ColourSummary", "Dataset", "DatasetError", "atomic_write",
    "beam_blocked", "direction", "display_srgb", "hue_difference", "in_plane_geometry",
    "interpolate", "make_dataset", "new_meta", "read_dataset", "remove_stale_temp_files",
    "rgb_colour", "signed_angle", "spectrum_colour", "spectrum_to_rgb", "spherical_angles",
    "write_dataset", "write_files_together",
]
