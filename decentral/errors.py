"""The one exception root of the toolkit and its per-concern subclasses.

The library never exits and never prints: it raises one of these, and only the command-line
front end (``sims.cli``) turns them into a one-line message and an exit status.
"""

__all__ = ["DecentralError", "InputError", "SolverError", "ProtocolError"]


class DecentralError(Exception):
    """Root of every error this toolkit raises on purpose."""


class InputError(DecentralError, ValueError):
    """Bad input: a file, a field or an argument that does not meet the contract.

    Parameters
    ----------
    message : str
        What is wrong, in one line.
    source : str, optional
        The file (or other origin) the bad value came from.
    field : str, optional
        The path of the offending field inside the source, e.g. ``steps[3].detections``.
    """

    def __init__(self, message: str, *, source: str | None = None, field: str | None = None):
        self.message = message
        self.source = source
        self.field = field
        super().__init__(self.__str__())

    def located(self, source: str) -> "InputError":
        """Return the same error attributed to ``source`` (keeps an existing attribution)."""
        return InputError(self.message, source=self.source or source, field=self.field)

    def __str__(self) -> str:
        where = ": ".join(part for part in (self.source, self.field) if part)
        return f"{where}: {self.message}" if where else self.message


class SolverError(DecentralError):
    """A numerical solver could not produce an answer the caller may use."""


class ProtocolError(DecentralError):
    """A message could not be decoded, or a protocol was driven out of its states."""
