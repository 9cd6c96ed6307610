"""The ``evpose`` command (DESIGN section 5): builds the parser from the command groups and dispatches.

``--json`` prints exactly one JSON document on stdout (:mod:`evpose.app.cli.json_output`); messages and
progress (:mod:`evpose.app.cli.progress`) go to stderr. Exit codes and error lines live in
:mod:`evpose.app.cli.errors`: 2 for bad input (the line names the file and the field, or the option),
1 when the system refuses a read or write, 130 when interrupted.

Building the parser imports no engine module (numpy, scipy, h5py...): each command imports what it
needs when it runs, so ``evpose --help`` and a refused option answer at once.
"""
from __future__ import annotations

import argparse
import sys

from evpose.app.cli.align import add_align_parsers
from evpose.app.cli.dataset import add_dataset_parser
from evpose.app.cli.errors import EXIT_BAD_INPUT
from evpose.app.cli.export import add_export_parser
from evpose.app.cli.gui import add_demo_parser, add_gui_parser
from evpose.app.cli.importers import add_import_parser
from evpose.app.cli.info import add_info_parser
from evpose.app.cli.scene import add_scene_parser
from evpose.app.cli.synth import add_synth_parser

__all__ = ["build_parser", "main"]

VERSION = "evpose 0.1.0"


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr (``evpose CMD: error: ...``, exit 2),
    like every other evpose error; the usage is one ``--help`` away. Sub-parsers inherit the class."""

    def error(self, message: str):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``evpose`` parser; each sub-command's ``func`` returns the exit status."""
    p = OneLineParser(prog="evpose", description="Verify, correct and export 6D object-pose "
                      "annotations of event-camera recordings.")
    p.add_argument("--version", action="version", version=VERSION)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_demo_parser(sub)
    add_synth_parser(sub)
    add_info_parser(sub)
    add_gui_parser(sub)
    add_export_parser(sub)
    add_import_parser(sub)
    add_scene_parser(sub)
    add_align_parsers(sub)
    add_dataset_parser(sub)
    return p


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Python warnings (e.g. an unknown object name in corrections.json) as one line on stderr."""
    print(f"evpose: warning: {message}", file=sys.stderr if file is None else file)


def main(argv=None) -> int:
    """Run ``evpose ARGV`` (default: the process arguments); returns the exit status."""
    import warnings

    warnings.showwarning = _show_warning
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
