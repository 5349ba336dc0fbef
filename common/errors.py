"""The project's own errors. Every failure a user can cause ends in one of these,
with a message naming what is wrong; never a bare traceback from deep inside."""


class LghccError(Exception):
    """Base class of every error lghcc raises on purpose."""


class BitstreamError(LghccError):
    """The bitstream is malformed: truncated, corrupted, or violates a constraint of the spec."""


class UnsupportedStreamError(BitstreamError):
    """The bitstream is well formed but uses a version, profile or unit this decoder does not support."""


class HashMismatchError(BitstreamError):
    """The decoded output does not match the hash carried in the stream."""


class InputError(LghccError):
    """The encoder's input (a scene, a file, an option) cannot be used; the message says why."""


class ResourceLimitError(LghccError):
    """The work is allowed by the spec but needs more than this run may use (``--max-memory``,
    ``--max-points``): not a fault of the stream or the input, so it is not a BitstreamError."""


class UsageError(LghccError):
    """A valid input asked for something it cannot give (the level-1 preview of a stream coded
    without the hierarchy): the command line is wrong for this input, exit status 2."""


class InputWarning(UserWarning):
    """The input was read, with something the user should know (the message says what); the
    programs print it as one line (lghcc.app.cliargs.run_cli)."""
