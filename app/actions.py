"""Keyboard shortcuts, defined once: the main window creates its actions from this table and
the help overlay (F1) and the README list the same rows."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Shortcut:
    name: str
    keys: tuple[str, ...]
    text: str
    section: str


SHORTCUTS: tuple[Shortcut, ...] = (
    # navigation
    Shortcut("step_back", ("Left",), "previous window", "Navigate"),
    Shortcut("step_forward", ("Right",), "next window", "Navigate"),
    Shortcut("step_back_10", ("Shift+Left",), "10 windows back", "Navigate"),
    Shortcut("step_forward_10", ("Shift+Right",), "10 windows forward", "Navigate"),
    Shortcut("go_start", ("Home",), "first window", "Navigate"),
    Shortcut("go_end", ("End",), "last window", "Navigate"),
    Shortcut("play", ("Space",), "play / pause", "Navigate"),
    # clock
    Shortcut("offset_minus", ("[",), "time offset − one step (panel step, default 100 µs)", "Clock"),
    Shortcut("offset_plus", ("]",), "time offset + one step", "Clock"),
    Shortcut("offset_minus_10", ("{",), "time offset − 10 steps", "Clock"),
    Shortcut("offset_plus_10", ("}",), "time offset + 10 steps", "Clock"),
    # pose: translation (mm) and rotation (degrees) in the axes chosen in the panel
    Shortcut("tx_minus", ("A",), "move object −x (step in mm; Shift ×10)", "Object pose"),
    Shortcut("tx_plus", ("D",), "move object +x", "Object pose"),
    Shortcut("ty_minus", ("W",), "move object −y (camera axes: up)", "Object pose"),
    Shortcut("ty_plus", ("S",), "move object +y (camera axes: down)", "Object pose"),
    Shortcut("tz_minus", ("Q",), "move object −z (camera axes: towards the camera)", "Object pose"),
    Shortcut("tz_plus", ("E",), "move object +z (camera axes: away)", "Object pose"),
    Shortcut("rx_minus", ("I",), "rotate object about −x (step in degrees; Shift ×10)", "Object pose"),
    Shortcut("rx_plus", ("K",), "rotate object about +x", "Object pose"),
    Shortcut("ry_minus", ("J",), "rotate object about −y", "Object pose"),
    Shortcut("ry_plus", ("L",), "rotate object about +y", "Object pose"),
    Shortcut("rz_minus", ("U",), "rotate object about −z", "Object pose"),
    Shortcut("rz_plus", ("O",), "rotate object about +z", "Object pose"),
    Shortcut("next_object", ("Tab",), "select the next object", "Object pose"),
    # review
    Shortcut("mark_verified", ("V",), "mark the window verified", "Review"),
    Shortcut("mark_rejected", ("R",), "mark the window rejected", "Review"),
    Shortcut("mark_flagged", ("F",), "flag the window", "Review"),
    Shortcut("next_unreviewed", ("N",), "go to the next unreviewed window", "Review"),
    Shortcut("next_flagged", ("Shift+N",), "go to the next flagged window", "Review"),
    # view
    Shortcut("toggle_mask", ("M",), "masks on/off", "View"),
    Shortcut("toggle_contour", ("C",), "silhouette contours on/off", "View"),
    Shortcut("toggle_box", ("B",), "3D boxes on/off", "View"),
    Shortcut("toggle_axes", ("X",), "object axes on/off", "View"),
    Shortcut("reset_zoom", ("0",), "fit the frame", "View"),
    Shortcut("rep_polarity", ("1",), "events: polarity (ON red, OFF blue)", "View"),
    Shortcut("rep_spike", ("2",), "events: spike (any event)", "View"),
    Shortcut("rep_three_channel", ("3",), "events: E-POSE 3-channel", "View"),
    Shortcut("rep_time_surface", ("4",), "events: time surface", "View"),
    Shortcut("rep_counts", ("5",), "events: counts", "View"),
    Shortcut("rep_voxel", ("6",), "events: voxel grid", "View"),
    Shortcut("window_shorter", ("-",), "halve the window (ms or events)", "View"),
    Shortcut("window_longer", ("=", "+"), "double the window", "View"),
    Shortcut("selected_only", ("H",), "overlays of the selected object only", "View"),
    Shortcut("outline_only", ("Shift+C",), "outlines only (no fill, boxes, axes)", "View"),
    Shortcut("help", ("F1",), "this help", "View"),
    # document
    Shortcut("open", ("Ctrl+O",), "open a scene", "File"),
    Shortcut("save", ("Ctrl+S",), "save corrections.json", "File"),
    Shortcut("export", ("Ctrl+E",), "export a corrected dataset", "File"),
    Shortcut("screenshot", ("F12",), "save a screenshot", "File"),
    Shortcut("undo", ("Ctrl+Z",), "undo", "Edit"),
    Shortcut("redo", ("Ctrl+Shift+Z", "Ctrl+Y"), "redo", "Edit"),
    Shortcut("quit", ("Ctrl+Q",), "quit", "File"),
)

#: (kind, axis, sign) of the pose-nudge shortcuts.
NUDGES = {f"{k}{a}_{s}": ("translate" if k == "t" else "rotate", "xyz".index(a), -1 if s == "minus" else 1)
          for k in "tr" for a in "xyz" for s in ("minus", "plus")}


def sentence_case(text: str) -> str:
    """A menu entry's text from a table row: the first letter capitalised, the rest as written (menus use sentence
    case throughout: "Go to the next unreviewed window", "Save corrections", "Open recent")."""
    return text[:1].upper() + text[1:]


def help_sections() -> list[tuple[str, list[tuple[str, str]]]]:
    """Rows for the help overlay, grouped by section in table order."""
    sections: dict[str, list[tuple[str, str]]] = {}
    for s in SHORTCUTS:
        sections.setdefault(s.section, []).append((" / ".join(s.keys), s.text))
    return list(sections.items())


#: Representation -> the name of its shortcut row.
REPRESENTATION_SHORTCUTS = {s.name[len("rep_"):]: s.name for s in SHORTCUTS if s.name.startswith("rep_")}


def is_single_key(sequence: str) -> bool:
    """A shortcut typed as text: one printable key, alone or with Shift (``"R"``, ``"Space"``, ``"["``,
    ``"Shift+N"``), as opposed to ``"Ctrl+S"``, ``"F1"`` or the arrows. These must not fire while a button has
    the keyboard focus or the user types in a field (:mod:`evpose.app.shortcut_guard`)."""
    key = sequence[len("Shift+"):] if sequence.startswith("Shift+") and len(sequence) > len("Shift+") else sequence
    return len(key) == 1 or key == "Space"
