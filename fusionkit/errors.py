"""The exception hierarchy of fusionkit.

Every error raised for bad user input, a bad configuration or a broken plugin is a
:class:`FusionkitError`, so ``except fusionkit.FusionkitError`` catches all of them. Messages
name the argument, what was expected and what was found (and the first bad index for data).
"""

from __future__ import annotations

__all__ = ["FusionkitError", "InputError", "ConfigError", "PluginError", "PluginWarning"]


class FusionkitError(Exception):
    """Base class of all fusionkit errors."""


class InputError(FusionkitError, ValueError):
    """Bad input data: wrong shape, wrong unit, non-monotonic time, a non-finite sample."""


class ConfigError(FusionkitError, ValueError):
    """A configuration that cannot be used (unknown parameter, out of range, inconsistent)."""


class PluginError(FusionkitError, LookupError):
    """An unknown plugin name, a plugin that failed to load, or a duplicate name."""


class PluginWarning(UserWarning):
    """A plugin that is installed but not used: e.g. a third-party plugin named like a built-in."""
