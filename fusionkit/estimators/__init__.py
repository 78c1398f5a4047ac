"""Estimators: propagate orientation from gyroscope rates."""
