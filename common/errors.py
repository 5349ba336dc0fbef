"""The project's own errors. Every failure a user can cause ends in one of these,
with a message naming what is wrong; never a bare traceback from deep inside."""


class LghccError(Exception):
    """Base class of every error lghcc raises on purpose."""


class BitstreamError(LghccError):
    """The bitstream is malformed: truncated, corrupted, or violates a constraint of the spec.

    ``condition``: the row of spec clause 8.2's table the stream breaks ('E1' .. 'E68'), set where
    the check raises it; None for a rejection that is no row of it (an unsupported profile). The
    conformance runner and the differential fuzzer compare it with what the stream is known to
    break, so it must survive pickling (a decoding worker process) and ``with_prefix``."""

    def __init__(self, *args, condition: str | None = None):
        super().__init__(*args)
        self.condition = condition

    def __reduce__(self):
        return _rebuild, (type(self), self.args, self.condition)


def _rebuild(cls, args, condition):
    """Unpickle a BitstreamError (or subclass) with its condition (Exception pickles only args)."""
    e = cls(*args)
    e.condition = condition
    return e


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
