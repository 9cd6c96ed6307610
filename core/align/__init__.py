"""Alignment of labels with events: scores, clock sync, refinement from edges."""
