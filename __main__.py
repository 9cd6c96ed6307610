"""``python -m evpose``: the ``evpose`` command."""
import sys

from evpose.app.cli import main

sys.exit(main())
