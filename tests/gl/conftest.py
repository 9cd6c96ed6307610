"""OpenGL (vispy) tests: need a real X display (pytest-xvfb provides Xvfb with GLX); skipped without."""
import os

import pytest


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "tests/gl/" in str(item.fspath).replace(os.sep, "/"):
            item.add_marker(pytest.mark.gl)


@pytest.fixture(autouse=True)
def _need_display():
    if not os.environ.get("DISPLAY"):
        pytest.skip("no X display for OpenGL (install Xvfb; pytest-xvfb starts it)")


@pytest.fixture
def session(scene_copy):
    from evpose.core.session.model import Session

    s = Session.open(scene_copy)
    s.set_time(s.time_range[0] + 300_000)
    yield s
    s.close()
