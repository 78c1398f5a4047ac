"""Filters: complete algorithms users pick by name."""
