"""easyWand import, kept at its first address: the importer lives in
:mod:`capture.importers.easywand` (docs/import.md)."""

from capture.importers.easywand import read_easywand, read_easywand_files, read_easywand_mat

__all__ = ["read_easywand", "read_easywand_files", "read_easywand_mat"]
