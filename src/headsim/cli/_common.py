"""Shared CLI helpers (atomic outputs live in :mod:`headsim._atomic`, usable by every layer)."""

from headsim._atomic import atomic_output_dir, atomic_output_file

__all__ = ["atomic_output_dir", "atomic_output_file"]
