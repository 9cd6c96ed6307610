"""Progress of a long command: a tqdm bar on stderr driven by the engine's ``progress(fraction, message)``
callbacks (DESIGN section 2: core functions take ``progress`` and know nothing of terminals).

The bar appears at the first callback, so a command that fails before any work prints its one error
line alone; ``-q`` turns it off. Log lines written through :meth:`Progress.write` appear above the bar.
"""
from __future__ import annotations

import sys

__all__ = ["Progress"]

#: Resolution of the bar: tenths of a percent.
STEPS = 1000
BAR_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining} {postfix}"


class Progress:
    """A ``progress(fraction, message="")`` callable showing a bar on stderr.

    Parameters
    ----------
    desc : str
        Label left of the bar (``"export epose"``).
    enabled : bool
        False: no bar (``-q``); the callable still accepts calls.
    leave : bool
        Keep the finished bar on screen (True) or clear it.

    Use as a context manager (the bar is closed on exit, also on errors)::

        with Progress(f"export {fmt}", not args.quiet) as progress:
            export_scene(..., progress=progress)
    """

    def __init__(self, desc: str, enabled: bool = True, *, leave: bool = True):
        self.desc = desc
        self.enabled = enabled
        self.leave = leave
        self.bar = None

    def __call__(self, fraction: float | None, message: str = "") -> None:
        """Move the bar to ``fraction`` (0..1; None keeps it where it is: a stage reporting progress within a
        step it cannot size) and show ``message``."""
        if not self.enabled:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=STEPS, desc=self.desc, unit="‰", file=sys.stderr, leave=self.leave,
                            dynamic_ncols=True, bar_format=BAR_FORMAT)
        if fraction is not None:
            self.bar.update(max(0, int(round(fraction * STEPS)) - self.bar.n))
        if message:
            self.bar.set_postfix_str(message, refresh=False)

    def write(self, line: str) -> None:
        """Print ``line`` on stderr, above the bar when one is shown."""
        if self.bar is not None:
            self.bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
