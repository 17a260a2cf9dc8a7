"""Reading movies and writing results: TIFF stacks, tables with sidecar JSON, atomically."""

from holofit.io.atomic import atomic_path, atomic_write_text
from holofit.io.movie import Movie, MovieError, open_movie
from holofit.io.tables import read_table, write_json, write_table
from holofit.io.tiffstack import TiffStackWriter, write_tiff_stack

__all__ = [
    "Movie",
    "MovieError",
    "TiffStackWriter",
    "atomic_path",
    "atomic_write_text",
    "open_movie",
    "read_table",
    "write_json",
    "write_table",
    "write_tiff_stack",
]
