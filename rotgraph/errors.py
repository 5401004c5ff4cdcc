"""The exceptions rotgraph raises.

Library users get these exceptions (never ``sys.exit``); the command line turns an
:class:`InputError` into ``rotgraph: error: FILE:LINE: message`` and exit code 3, an
:class:`OptionError` into exit code 2. Both are also ``ValueError``s.
"""

from __future__ import annotations

__all__ = ["RotgraphError", "InputError", "UnsolvableError", "OptionError", "UnknownOptionError"]


class RotgraphError(Exception):
    """Base class of every error rotgraph raises on purpose.

    Parameters
    ----------
    message : str
        What went wrong, one sentence.
    """


class InputError(RotgraphError, ValueError):
    """Bad input: unreadable, malformed or inconsistent data.

    ``path`` and ``line`` (1-based) say where, when the data came from a file.

    Parameters
    ----------
    message : str
        What is wrong with the data.
    path : str or os.PathLike, optional
        The file the data came from.
    line : int, optional
        The 1-based line of ``path``.

    Attributes
    ----------
    message : str
        The message without the location.
    path : str or None
        The file, as a string.
    line : int or None
        The line.
    """

    def __init__(self, message: str, path: str | None = None, line: int | None = None):
        self.message = message
        self.path = None if path is None else str(path)
        self.line = line
        super().__init__(self.location() + message)

    def location(self) -> str:
        if self.path is None:
            return ""
        if self.line is None:
            return f"{self.path}: "
        return f"{self.path}:{self.line}: "


class UnsolvableError(RotgraphError):
    """The problem cannot be solved as asked (e.g. no edge survives filtering).

    Parameters
    ----------
    message : str
        Why not.
    """


class OptionError(RotgraphError, ValueError):
    """A usage error: a bad option value (an unknown method, format or loss, a scale that is
    not positive), options that cannot go together, an output name of no known format, a
    batch with nothing to do. The command line exits 2 with the message, as for click's own
    usage errors. Also a ``ValueError``, so ``except ValueError`` keeps catching it.

    Parameters
    ----------
    message : str
        Which option is wrong and what it should be.
    """


class UnknownOptionError(OptionError, TypeError):
    """A keyword argument that is no option of the estimator called (e.g. ``rotgraph.mean(R,
    tolerance=1e-6)``). An :class:`OptionError`, and a ``TypeError`` as Python's own
    unexpected keyword argument is, so ``except TypeError`` keeps catching it.

    Parameters
    ----------
    message : str
        The unknown name and the options there are.
    """
