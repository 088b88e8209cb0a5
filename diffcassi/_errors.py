"""Exceptions of diffcassi.

Every error raised by the compiled part derives from :class:`DiffcassiError`; bad values, shapes and dtypes
are also :class:`ValueError` (:class:`DiffcassiValueError`), missing or unreadable files also
:class:`OSError` (:class:`DiffcassiFileError`). The message is the Rust library's.
"""


class DiffcassiError(Exception):
    """Base class of diffcassi's errors."""


class DiffcassiValueError(DiffcassiError, ValueError):
    """A bad value, shape or dtype (the message names the argument, the expected and the actual)."""


class DiffcassiFileError(DiffcassiError, OSError):
    """A missing or unreadable file (the message names the path)."""
