"""The user's document: corrections, undo history, pose edits, review marks, saving."""
