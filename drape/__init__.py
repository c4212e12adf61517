"""drape: draping simulation of woven composite fabrics."""
from pathlib import Path as _Path

__version__ = "0.1.0"

# The gmsh builders live in the checkout's top-level geometry/ and are installed as
# drape.geometry (pyproject.toml). Run from a plain checkout (PYTHONPATH=.), the checkout's
# root joins this package's search path so that `import drape.geometry` finds them there too.
_checkout = _Path(__file__).resolve().parent.parent
if (_checkout / "geometry" / "blank.py").is_file() and str(_checkout) not in __path__:
    __path__.append(str(_checkout))
