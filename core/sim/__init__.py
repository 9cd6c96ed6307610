"""Synthetic scenes with ground truth and the event simulator."""
