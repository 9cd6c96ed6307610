"""Widget tests run under pytest-qt on the Xvfb display pytest-xvfb starts (offscreen without one)."""
import pytest


@pytest.fixture
def session(scene_copy):
    from evpose.core.session.model import Session

    s = Session.open(scene_copy)
    s.set_time(s.time_range[0] + 300_000)  # mid-motion: events and objects in view
    yield s
    s.close()
