"""Sensor models: plugins that correct the raw samples before a pipeline reads them."""
