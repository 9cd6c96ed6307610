"""evpose: see, verify, correct and export 6D object-pose annotations of event-camera recordings.

The repository's role folders are installed as the subpackages of this one package
(``evpose.core``, ``evpose.widgets``, ``evpose.app``, ``evpose.resources``); see ``setup.py``.
"""
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("evpose")
except PackageNotFoundError:  # pragma: no cover - running from a source tree that is not installed
    __version__ = "unknown"
