"""The ``evpose`` command line (DESIGN section 5). Importing it loads no Qt: only ``evpose gui``
and ``evpose demo`` start the app, by a lazy import inside their commands."""
from evpose.app.cli.main import main

__all__ = ["main"]
