"""The installed package's version, apart from the package's ``__init__`` so modules can read it without importing the package."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("hortishape")
except PackageNotFoundError:  # running from a source tree without install
    __version__ = "0.0.0+unknown"
