"""Detectors: turn the sensor stream into per-sample events and flags."""
