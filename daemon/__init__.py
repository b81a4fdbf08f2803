"""placecell: place-based localisation daemon (the service and the method)."""

__version__ = "0.1.0"
