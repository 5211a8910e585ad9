"""Errors that the command line reports as one clear line (no traceback)."""

from __future__ import annotations


class BubblefitError(Exception):
    """A problem with the user's input or environment, phrased for the user.

    The command line prints ``bubblefit: error: <message>`` on stderr and exits
    with status 2 (bad input) or 1 (a computation that failed, e.g. a fit that did
    not converge and was asked to be strict).
    """

    exit_code = 2


class InputError(BubblefitError):
    """A file, value or option given by the user cannot be used."""


class OutputError(InputError):
    """An output cannot be written (missing folder, full disk, a writer's error), or it
    would overwrite one of the command's inputs; the earlier file is left as it was."""


class ComputationError(BubblefitError):
    """A computation failed for a reason the user should know about."""

    exit_code = 1
