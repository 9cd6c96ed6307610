"""Widget tests run under pytest-qt on the Xvfb display pytest-xvfb starts (offscreen without one)."""
import os

import pytest

if not os.environ.get("DISPLAY"):
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


@pytest.fixture
def session(scene_copy):
    from core.session import Session

    s = Session.open(scene_copy)
    s.set_time(s.time_range[0] + 300_000)  # mid-motion: events and objects in view
    yield s
    s.close()
