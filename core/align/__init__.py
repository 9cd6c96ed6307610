"""Alignment of labels with events: scores, clock sync, refinement from edges.

* scores: :mod:`score` (one window), :mod:`score_table` (a sequence);
* clock from the event rate: :mod:`estimate` runs the stages (:mod:`proxy`, :mod:`scene_proxy`,
  :mod:`rate_series`, :mod:`correlation`, :mod:`correlation_peak`, :mod:`segments`,
  :mod:`poisson_fit`, :mod:`likelihood`, :mod:`rate_refine`) into a :mod:`sync_result`;
  :mod:`minima_baseline` is the E-POSE method (``docs/sync.md``);
* refinement from edges: the objective :mod:`edges` (on :mod:`mesh_edges`, :mod:`contours`,
  :mod:`event_windows`) fitted by :mod:`pose_refine` and :mod:`clock_refine` (with
  :mod:`clock_fit`; :mod:`sync_edges` starts it at a rate estimate) into a
  :mod:`refine_result` (``docs/refine.md``);
* :mod:`apply`: an accepted clock estimate as corrections, one undo step.
"""
