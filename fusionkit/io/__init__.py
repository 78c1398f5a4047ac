"""Readers: :func:`load` dispatches on the file type."""

from .loaders import load, load_broad, load_csv, write_csv

__all__ = ["load", "load_broad", "load_csv", "write_csv"]
