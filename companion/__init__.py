"""companion: real-time navigation companion for ArduPilot vehicles."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("companion")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"
