"""Benchmarks behind ``torchtof bench …``: each returns a JSON-able dict and prints a table."""

from .timing import time_call

__all__ = ["time_call"]
