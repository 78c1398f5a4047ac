"""Benchmarking: metrics (BROAD definitions) and side-by-side runs."""

from .metrics import broad_errors, rms_errors

__all__ = ["broad_errors", "rms_errors"]
