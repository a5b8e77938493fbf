"""Exceptions that gspc reports to users as one line (the CLI prints ``str(err)``)."""


class GspcError(Exception):
    """Base class: anything a user can cause with bad input or options."""


class InputError(GspcError):
    """An input file (scene, cameras, images) is missing, malformed or inconsistent."""


class ValueRangeError(InputError):
    """A scene holds a value too large to code at the lambda asked for (a larger lambda may code it)."""


class FormatError(GspcError):
    """A .gspc file violates the container spec (see spec/gspc-format.md)."""


class CodecError(GspcError):
    """A codec payload inside a valid container cannot be decoded."""


class NothingCodedError(CodecError):
    """Every Gaussian was removed (transparent, unseen or, at a coarse lambda, not worth its bytes)."""


class DeviceError(GspcError):
    """A requested compute device or backend is unavailable."""
