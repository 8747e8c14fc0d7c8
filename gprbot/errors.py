"""The one error tree of gprbot: every failure a user can cause or meet is a GprbotError."""

from __future__ import annotations


class GprbotError(Exception):
    """Base of all gprbot errors; the message says what went wrong and what to do."""


class ConfigError(GprbotError):
    """A configuration or scene file is wrong: unknown key, wrong type, out-of-range value."""


class DataFormatError(GprbotError):
    """A data file (DZT, PLY, run log) is truncated, corrupt or not of the expected format."""


class ProtocolError(GprbotError):
    """A device or shell protocol frame is malformed."""


class DriverError(GprbotError):
    """A device is absent, does not answer, or the wrong device answers."""


class ModelError(GprbotError):
    """A model file is missing, corrupt or does not match its model card."""


class InterpretationError(GprbotError):
    """A B-scan cannot be interpreted (empty, too short, no usable signal)."""


class UsageError(GprbotError):
    """A command-line option has a value no run could use (the CLI exits 2, as argparse does)."""
