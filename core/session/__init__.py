"""The app model the GUI views: a session (:mod:`.model`: document + view state, one change
signal), its view state (:mod:`.view_state`), the frames and space-time clouds computed for it in
worker threads (:mod:`.frames`), and the whole-sequence timeline curves (:mod:`.timeline`)."""
