"""Errors raised by the bag tools, each with a message that says what to do."""

from __future__ import annotations


class BagError(Exception):
    """A bag directory or MCAP file is missing, malformed, or does not hold what was asked for."""


class MessageDefinitionError(BagError):
    """A message type's definition, hash or Python class cannot be found."""
