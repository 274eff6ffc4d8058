"""matup's exceptions. Every message is the one the ``matup`` command line prints."""


class MatupError(Exception):
    """Something matup could not do."""


class InvalidInput(MatupError, ValueError):
    """A setting, an array or a network's output that matup cannot use."""


class FileError(MatupError, OSError):
    """A file or folder that cannot be read or written, or a material that is not whole."""
