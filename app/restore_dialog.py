"""The crash-restore question: what an autosaved journal would change, in words, before the user restores it.

The question names each part of the document the restore sets, with its value and the value now: the clock
offset and skew corrections, the hand-eye correction, which objects' poses, and how many review marks."""
from __future__ import annotations

import datetime

import numpy as np

from evpose.core.document.corrections import Corrections
from evpose.core.document.journal import restore_target
from evpose.core.document.pose_edit import delta_components

TITLE = "Restore unsaved corrections?"


def journal_changes(current: Corrections, autosaved: Corrections, source: str = "journal") -> list[str]:
    """One line per part of ``current`` that restoring ``autosaved`` changes (what
    :meth:`evpose.core.session.model.Session.restore_journal` will set), and the conflicts it resolves."""
    target, conflicts = restore_target(autosaved, current, source)
    keys = current.differing_keys(target)
    lines = []
    if ("offset_us",) in keys:
        lines.append(f"clock offset correction {target.offset_us / 1000:+.3f} ms "
                     f"(now {current.offset_us / 1000:+.3f} ms)")
    if ("skew_ppm",) in keys:
        lines.append(f"clock skew correction {target.skew_ppm:+.3f} ppm (now {current.skew_ppm:+.3f} ppm)")
    if ("hand_eye",) in keys:
        rv, t = delta_components(target.hand_eye_delta)
        lines.append(f"hand-eye correction {np.linalg.norm(rv):.2f}°, {np.linalg.norm(t):.2f} mm")
    objects = [k[1] for k in keys if k[0] == "object"]
    if objects:
        reset = [n for n in objects if n not in target.object_deltas]
        many = "s" * (len(objects) > 1)
        text = f"pose{many} of {len(objects)} object{many}: {', '.join(objects)}"
        lines.append(text + (f" ({', '.join(reset)} back to the scene's pose)" if reset else ""))
    if ("reviews",) in keys:
        n, now = len(target.reviews), len(current.reviews)
        lines.append(f"{n} review mark{'s' * (n != 1)} (now {now})")
    if conflicts:
        lines.append("the autosaved value is kept over the file's for " + ", ".join(c.field for c in conflicts))
    return lines


def restore_question(current: Corrections, autosaved: Corrections, journal_mtime: float,
                     source: str = "journal") -> str:
    """The question's text: when the corrections were autosaved and what restoring them sets."""
    when = datetime.datetime.fromtimestamp(journal_mtime).strftime("%Y-%m-%d %H:%M")
    lines = journal_changes(current, autosaved, source)
    what = "\n".join(f"  • {line}" for line in lines) if lines else "  • nothing that differs from the saved file"
    return (f"Corrections autosaved on {when} were never saved (the app may have crashed).\n\n"
            f"Restoring them sets:\n{what}\n\nRestore them? (Ctrl+Z undoes the restore.)")
