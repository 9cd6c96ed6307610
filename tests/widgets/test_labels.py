"""Readout: a text that changes every frame must not relayout (and so repaint) the window."""
from PySide6 import QtCore, QtWidgets

from evpose.widgets.labels import Readout


class _LayoutRequests(QtCore.QObject):
    def __init__(self):
        super().__init__()
        self.n = 0

    def eventFilter(self, obj, ev):  # noqa: N802 (Qt API)
        if ev.type() == QtCore.QEvent.LayoutRequest:
            self.n += 1
        return False


def _host(qtbot, label):
    host = QtWidgets.QWidget()
    qtbot.addWidget(host)
    row = QtWidgets.QHBoxLayout(host)
    row.addWidget(QtWidgets.QPushButton("left"))
    row.addWidget(label, 1)
    host.resize(500, 40)
    host.show()
    qtbot.waitExposed(host)
    qtbot.wait(50)                      # let the first layout settle
    spy = _LayoutRequests()
    host.installEventFilter(spy)
    return host, spy


def test_new_text_does_not_relayout(qtbot):
    r = Readout("t = 9999.9999 s   99,999 events", stretch=True)
    host, spy = _host(qtbot, r)
    hint, geom = r.sizeHint(), r.geometry()
    for text in ("t = 0.1 s", "a much longer text than the template ever was, and then some more", ""):
        r.setText(text)
        QtWidgets.QApplication.processEvents()
        assert r.text() == text and r.sizeHint() == hint and r.geometry() == geom
    assert spy.n == 0
    # the reason it exists: a QLabel in the same place asks for a new layout at each text
    label = QtWidgets.QLabel("x")
    host2, spy2 = _host(qtbot, label)
    label.setText("a new and longer text")
    QtWidgets.QApplication.processEvents()
    assert spy2.n >= 1


def test_fixed_width_from_the_template_and_copy(qtbot):
    r = Readout("u 345, v 259 | 999 ev", "u 1, v 2 | 3 ev")
    host, _ = _host(qtbot, r)
    assert r.width() == r.sizeHint().width() >= r.fontMetrics().horizontalAdvance("u 345, v 259 | 999 ev")
    assert r.sizePolicy().horizontalPolicy() == QtWidgets.QSizePolicy.Fixed
    copy = r.actions()[0]
    copy.trigger()
    assert QtWidgets.QApplication.clipboard().text() == "u 1, v 2 | 3 ev"
    img = r.grab().toImage()        # the text is drawn: some dark pixels
    dark = sum(1 for x in range(0, img.width(), 2) for y in range(img.height())
               if img.pixelColor(x, y).lightness() < 100)
    assert dark > 5


def test_right_text_wins_when_space_is_short(qtbot):
    r = Readout("t 0.1234 s   win 10 ms", "t 0.1234 s   win 10 ms   12,345 ev   on masks 45.6%", stretch=True)
    host, spy = _host(qtbot, r)
    r.setRightText("u 12, v 34 | 5 ev | box @ 412.0 mm")
    QtWidgets.QApplication.processEvents()
    assert r.rightText() == "u 12, v 34 | 5 ev | box @ 412.0 mm" and spy.n == 0
    r.actions()[0].trigger()
    assert QtWidgets.QApplication.clipboard().text() == r.text() + "  " + r.rightText()
    # narrow: the right text is drawn whole at the right edge, the left one is elided
    host.resize(r.fontMetrics().horizontalAdvance(r.rightText()) + 140, 40)
    qtbot.wait(50)
    img = r.grab().toImage()
    cols = [x for x in range(img.width()) if any(img.pixelColor(x, y).lightness() < 100 for y in range(img.height()))]
    assert cols and cols[-1] > img.width() - 12          # text reaches the right edge
