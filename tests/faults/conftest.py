"""Fixtures of the fault tests; the harness itself is :mod:`fault_harness`."""
from fault_harness import small_tmpfs  # noqa: F401  (fixture)
