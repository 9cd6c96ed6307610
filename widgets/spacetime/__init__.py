"""The spacetime widgets."""
