"""Work-arounds for defects of specific Qt binding releases (applied at app start and in tests)."""
from __future__ import annotations

import ctypes
import sys

_applied = False


def guard_pyside_refcount_leak() -> bool:
    """PySide6 6.12.0 on CPython 3.11 drops a reference to ``None`` on every call of a void C++
    method (and to ``True``/``False`` on some paths), as if they were immortal as on 3.12+. A few
    10^4 repaints bring ``None``'s count to 0 and abort the interpreter ("Fatal Python error:
    none_dealloc"). Where the leak is detected, the three singletons are made effectively
    immortal (their count raised by 2^40), which is what CPython 3.12+ does for them anyway.

    Returns True when the guard was applied. A no-op on Python >= 3.12 and on bindings without
    the leak; idempotent.
    """
    global _applied
    if _applied or sys.version_info >= (3, 12) or not hasattr(ctypes, "pythonapi"):
        return _applied
    from PySide6 import QtCore

    probe = QtCore.QObject()
    before = sys.getrefcount(None)
    for _ in range(200):
        probe.setObjectName("probe")
    if sys.getrefcount(None) >= before - 100:
        return False
    for obj in (None, True, False):
        ctypes.c_ssize_t.from_address(id(obj)).value += 1 << 40
    _applied = True
    return True


def share_gl_contexts() -> None:
    """Share OpenGL resources between every GL widget of the application (``Qt.AA_ShareOpenGLContexts``; must be set
    before the ``QApplication`` exists). A ``QOpenGLWidget`` moved to another top-level window — a dock floated or
    docked again — gets a new context; without sharing, the space-time view's vispy buffers and programs belonged to
    the old one, and the floated view drew nothing but OpenGL errors until docked again."""
    from PySide6 import QtCore

    if QtCore.QCoreApplication.instance() is None:
        QtCore.QCoreApplication.setAttribute(QtCore.Qt.AA_ShareOpenGLContexts)
