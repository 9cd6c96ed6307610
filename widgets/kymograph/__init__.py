"""The kymograph widgets."""
