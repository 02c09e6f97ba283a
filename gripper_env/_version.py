"""The package version (one place: the library, its files and the wheel read it)."""

__version__ = "0.1.0"
