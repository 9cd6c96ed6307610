"""The timeline widgets."""
