"""The crash-restore question: what an autosaved journal would change, in words, before the user restores it.

The question names each part of the document the restore sets, with its value and the value now: the clock
offset and skew corrections, the hand-eye correction, which objects' poses, and how many review marks. Where the
journal and the saved file both changed a field since the journal's edits began, it names both values and the
user chooses (:data:`CHOICES`); the saved value is the default, so a restore never silently drops saved work."""
from __future__ import annotations

import datetime

import numpy as np

from evpose.core.document.corrections import Corrections
from evpose.core.document.journal import JournalOffer
from evpose.core.document.pose_edit import delta_components

TITLE = "Restore unsaved corrections?"
#: The answers when the journal and the saved file disagree on a field: (key, button text); the first is the default.
CHOICES = [("keep_saved", "Restore, keep saved values"), ("take_autosaved", "Restore, take autosaved values"),
           ("discard", "Discard autosave")]


def journal_changes(current: Corrections, offer: JournalOffer, take_autosaved: bool = False) -> list[str]:
    """One line per part of ``current`` that restoring ``offer`` changes (what
    :meth:`evpose.core.session.model.Session.restore_journal` will set with ``take_autosaved``)."""
    target = offer.target(take_autosaved)
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
    return lines


def restore_question(current: Corrections, offer: JournalOffer, journal_mtime: float) -> str:
    """The question's text: when the corrections were autosaved, what restoring them sets, and (with conflicts)
    both values of every field the saved file changed too."""
    when = datetime.datetime.fromtimestamp(journal_mtime).strftime("%Y-%m-%d %H:%M")
    lines = journal_changes(current, offer)
    what = "\n".join(f"  • {line}" for line in lines) if lines else "  • nothing that differs from the saved file"
    text = (f"Corrections autosaved on {when} were never saved (the app may have crashed).\n\n"
            f"Restoring them sets:\n{what}\n")
    if not offer.conflicts:
        return text + "\nRestore them? (Ctrl+Z undoes the restore.)"
    later = "after" if offer.file_newer else "before"
    both = "\n".join(f"  • {c.field}: autosaved {c.local}, saved {c.disk}" for c in offer.conflicts)
    return (text + f"\nThe saved file was changed since these edits began (last saved {later} the autosave), "
            f"and differs on:\n{both}\n\nRestore keeps the saved values there unless you take the autosaved ones. "
            "(Ctrl+Z undoes the restore.)")
