"""Errors a user can cause. The CLI prints their message and exits 1, never a traceback."""


class FieldDiagError(Exception):
    """Base class of every error caused by input the user can fix.

    The message must say what went wrong and what to do about it.
    """


class SessionError(FieldDiagError):
    """A session file is missing, unreadable, malformed or would be overwritten."""


class ChannelNotFoundError(SessionError):
    """A channel, role or signal asked for is not in the session."""


class ImportFormatError(FieldDiagError):
    """A file being imported is malformed (missing column, bad number, bad time axis...)."""


class DbcError(FieldDiagError):
    """A CAN database (DBC) is missing or unreadable, or lacks a message or signal asked for."""


class InsufficientDataError(FieldDiagError):
    """The recording cannot support the requested answer (too short, too little excitation...)."""


class DeviceError(FieldDiagError):
    """A device could not be opened or spoke a protocol we do not understand."""


class InvalidValueError(FieldDiagError):
    """A number or option the user gave is not finite or outside its physical range."""


class OutputError(SessionError):
    """An output cannot be written where asked (no such folder, read-only, full disk, or the
    target is not a regular file)."""
