"""Errors that reach the user. Each names the input it is about."""
from __future__ import annotations

from pathlib import Path


class CanopyError(Exception):
    """Base class for errors the launcher reports as one line, without a traceback."""


class InputError(CanopyError):
    """Bad input: a missing file, a corrupt image, a calibration without a field.

    ``source`` names the file, folder or frame; ``problem`` says what is wrong.
    """

    def __init__(self, source: str | Path, problem: str):
        self.source = str(source)
        self.problem = problem
        super().__init__(f"{self.source}: {problem}")


class ConfigError(InputError):
    """A parameter file or value that cannot be used."""


class ProtocolError(CanopyError):
    """A malformed or incompatible message on the bus."""


class InputWarning(UserWarning):
    """Input that is used, but not as given (converted images, unmatched files).

    The launcher prints it as one ``warning:`` line naming the input.
    """


def warn_input(source: str | Path, problem: str) -> None:
    import warnings

    warnings.warn(InputWarning(f"{source}: {problem}"), stacklevel=2)
