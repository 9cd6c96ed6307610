"""The dataset view's *Campaign fit* box: the group fit that ``evpose dataset refine --joint --shared … --apply``
recorded in ``campaign_fit.json``, read-only, one line per shared term with its sigma (composed by
:func:`evpose.core.dataset.campaign_view.campaign_lines`).

The box shows the lines it is given and knows nothing of files; their first line says what they are (the fit's
headline "Campaign fit of 3 scenes: …", the hint that there is none, or the error naming the file), so the box has
no title of its own and lines up with the detail pane beside it. A hint is grey, an error red.
"""
from __future__ import annotations

from PySide6 import QtGui, QtWidgets

__all__ = ["CampaignPanel"]

#: Text colour per state of :func:`~evpose.core.dataset.campaign_view.campaign_lines` (None: the palette's).
STATE_COLOURS = {"ok": None, "absent": "#777777", "error": "#b00020"}


class CampaignPanel(QtWidgets.QWidget):
    """Read-only lines of the dataset's campaign fit (per group: each shared term's change ± 1 sigma, what its
    scenes stored, the fit's notes)."""

    def __init__(self, parent=None):
        super().__init__(parent)
        self.state = "absent"
        self.text = QtWidgets.QPlainTextEdit(readOnly=True)
        self.text.setLineWrapMode(QtWidgets.QPlainTextEdit.WidgetWidth)
        self.text.setPlaceholderText("Campaign fit: not read yet")
        self.tip = ("the campaign fit of the dataset.toml groups (evpose dataset refine --joint --shared … --apply): "
                    "each shared term's change from its start, translation in mm and rotation in degrees, ± one "
                    "standard error; which scenes stored it (their corrections' revision)")
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 4, 4, 4)           # as the detail pane's, so that the two text boxes line up
        layout.addWidget(self.text)

    def show_lines(self, state: str, lines: list[str], source: str = "") -> None:
        """Show ``lines`` in ``state`` ("ok", "absent" or "error"); ``source``: the record's path (in the tooltip)."""
        self.state = state
        text = "\n".join(lines)
        if self.text.toPlainText() != text:
            self.text.setPlainText(text)
        palette, colour = self.text.palette(), STATE_COLOURS.get(state)
        palette.setColor(QtGui.QPalette.Text, QtGui.QColor(colour) if colour else self.palette().text().color())
        self.text.setPalette(palette)
        self.text.setToolTip(f"{source}\n{self.tip}" if source else self.tip)

    def lines(self) -> list[str]:
        """The lines shown."""
        return self.text.toPlainText().splitlines()
