"""File input/output: atomic writes, view stacks (TIFF/Zarr), raw frame streams."""
