"""drape: draping simulation of woven composite fabrics."""
__version__ = "0.1.0"
