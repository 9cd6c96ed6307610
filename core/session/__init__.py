"""The app model the GUI views: a session (:mod:`.model`: document + view state, one change signal) and its view
state (:mod:`.view_state`). What the views show is computed from a session's snapshots in :mod:`evpose.core.views`."""
