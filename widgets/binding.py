"""Bind a view to a core signal for the view's lifetime.

Core signals hold a view's bound method weakly (:mod:`evpose.core.signals`), but Qt deletes the C++
side of a widget (its dock closed, the session replaced) before Python frees the wrapper, and a
call in between would reach a deleted widget. :func:`connect_view` therefore also ends the
subscription when the view is destroyed.
"""
from __future__ import annotations

from typing import Callable

from PySide6 import QtCore

from evpose.core.signals import Connection, Signal


def connect_view(view: QtCore.QObject, signal: Signal, slot: Callable, kinds=None) -> Connection:
    """Subscribe ``slot`` (normally a method of ``view``: held weakly) to ``signal`` until ``view``
    is destroyed, for the change ``kinds`` it shows (None: all); returns the
    :class:`~evpose.core.signals.Connection` (to disconnect earlier)."""
    conn = signal.connect(slot, kinds)
    view.destroyed.connect(conn.disconnect)
    return conn
