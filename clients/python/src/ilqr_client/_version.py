"""The package version: the single source for ``pyproject.toml`` and the User-Agent header."""

__version__ = "0.1.0"
