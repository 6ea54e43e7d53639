"""Errors of bad user input shared by every layer (the CLI maps them to exit code 2)."""
from __future__ import annotations

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad input other than the scene file (command-line options, campaign settings):
    the message is one line naming the option, the value and what is allowed."""
