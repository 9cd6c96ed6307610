"""What an export did: :class:`ExportSummary`, returned by every export and printed by the CLI."""
from __future__ import annotations

import copy
from dataclasses import dataclass, field, fields

import numpy as np

from evpose.core.export.windows import REVIEW_NO_LABEL

__all__ = ["ExportSummary", "set_unlabeled", "count_review_usage"]


@dataclass
class ExportSummary:
    """What an export did.

    Attributes
    ----------
    windows_total : int
        Windows of the tiling (before any filter).
    selected : int
        Windows left after ``only_verified``.
    written : int
        Windows whose outputs this run wrote.
    skipped_complete : int
        Windows already complete from an earlier run with the same configuration.
    unlabeled : int
        Selected windows without labels (label time outside the trajectory).
    unlabeled_windows : list of dict
        ``{"index", "t_label_us", "reason"}`` per unlabeled window.
    unlabeled_reasons : dict
        reason -> number of windows.
    filtered_unverified : int
        Windows left out by ``only_verified``.
    review_marked : int
        ``only_verified``: windows that a verified review mark overlaps (for an exported object).
    review_unused : int
        Of those, windows not exported (not selected, or selected without a label).
    review_unused_reasons : dict
        reason -> number of those windows (:mod:`evpose.core.export.windows`: ``REVIEW_PARTLY``, ``REVIEW_MIXED``,
        ``REVIEW_STALE``, ``REVIEW_NO_LABEL``).
    include_stale : bool
        ``only_verified``: stale verified marks counted as verified.
    runtime_s : float
    out_dir : str
    files : list of str
        Every file of the export, relative to ``out_dir`` (including those written by an earlier run).
    timings_s : dict
        Seconds per stage (``events``, ``annotate``, ``images``, ``mat``, ``write``) summed over the
        windows processed in this run, over all processes.
    events_only : bool
        The scene has no trajectory and no objects: event frames without labels (``h5`` only).
    """

    format: str = ""
    windows_total: int = 0
    selected: int = 0
    written: int = 0
    skipped_complete: int = 0
    unlabeled: int = 0
    unlabeled_windows: list = field(default_factory=list)
    unlabeled_reasons: dict = field(default_factory=dict)
    filtered_unverified: int = 0
    #: windows left out because a label's sigma exceeded --max-label-sigma-mm / --max-label-sigma-deg
    filtered_label_sigma: int = 0
    review_marked: int = 0
    review_unused: int = 0
    review_unused_reasons: dict = field(default_factory=dict)
    include_stale: bool = False
    runtime_s: float = 0.0
    out_dir: str = ""
    files: list = field(default_factory=list)
    timings_s: dict = field(default_factory=dict)
    jobs: int = 1
    config_sha256: str = ""
    #: jobs > 1: seconds from creating the process pool until its first chunk of results came back,
    #: minus that chunk's processing time (spawn, imports, opening the scene in each worker).
    pool_startup_s: float = 0.0
    events_only: bool = False
    #: on a cluster: the windows of each chunk, in the order handed out (sized from the measured CPU per window,
    #: :class:`~evpose.core.export.chunks.ChunkPlanner`); empty otherwise
    chunks: list = field(default_factory=list)

    def to_json(self, *, with_files: bool = True) -> dict:
        """A JSON-able copy (``with_files=False``: ``n_files`` instead of the list). The file list, one name per
        file (16 a 5-object E-POSE window), is copied as a list of its strings: ``dataclasses.asdict`` deep-copied
        it name by name, ~0.5 ms per window in the dataset export's driver (issue 27.2)."""
        d = {}
        for f in fields(self):
            if f.name != "files":
                d[f.name] = copy.deepcopy(getattr(self, f.name))
            elif with_files:
                d["files"] = list(self.files)
        if not with_files:
            d["n_files"] = len(self.files)
        return d


def set_unlabeled(summary: ExportSummary, unlabeled: list[dict]) -> None:
    """Record the selected windows without a label (:func:`evpose.core.export.windows.unlabeled_windows`)
    and count them per reason."""
    summary.unlabeled = len(unlabeled)
    summary.unlabeled_windows = unlabeled
    for u in unlabeled:
        summary.unlabeled_reasons[u["reason"]] = summary.unlabeled_reasons.get(u["reason"], 0) + 1


def count_review_usage(summary, windows, touched, reasons, unlabeled_idx, include_stale) -> None:
    """Count the windows verified marks touch and why those not exported were left out."""
    summary.include_stale = bool(include_stale)
    summary.review_marked = int(np.count_nonzero(touched))
    out: dict = {}
    for i in np.flatnonzero(touched):
        why = reasons[i] if reasons[i] is not None else (REVIEW_NO_LABEL if windows[i].index in unlabeled_idx else None)
        if why is not None:
            out[why] = out.get(why, 0) + 1
    summary.review_unused = sum(out.values())
    summary.review_unused_reasons = out
