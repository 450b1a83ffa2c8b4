"""The package's version, in one place (``lnn_torch.__version__``; the build reads it here)."""

__version__ = "0.1.0"
