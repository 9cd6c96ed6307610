"""The ``evpose`` command line (DESIGN section 5): one module per command group (``info``, ``synth``,
``gui`` with ``demo``, ``export``, ``importers``, ``align`` with ``sync`` and ``refine``), one place for
exit codes and error lines (``errors``), JSON output (``json_output``) and progress bars (``progress``).
Importing it loads no Qt and no engine module: only ``evpose gui`` and ``evpose demo`` start the app, by a
lazy import inside their commands."""
from evpose.app.cli.main import main

__all__ = ["main"]
