"""companion: real-time navigation companion for ArduPilot vehicles."""

#: the one place the version is set: pyproject.toml reads it (setuptools' attr:, without importing the package)
__version__ = "0.1.0"
