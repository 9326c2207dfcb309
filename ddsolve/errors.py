"""Exceptions raised by ddsolve.

Every error caused by bad user input is an :class:`InputError`. Its message is
one line that names the offending field, so that the command line can print it
as it is and exit with status 2.
"""
from __future__ import annotations


class InputError(ValueError):
    """Invalid user input (scene, configuration or solver options).

    Parameters
    ----------
    field : str
        Name of the offending field, e.g. ``"subdomains"``.
    message : str
        What is wrong, in one line.
    """

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}")
