"""The frame widgets."""
