"""Exceptions raised at the edges (files, config, command line); vector code never raises."""


class VirtualGPSError(Exception):
    """Base of every error virtualgps reports to the user as one line."""


class InputFileError(VirtualGPSError):
    """A file (TLE, scene, pose log, config, profile) could not be read.

    The message names the file, the line (when there is one) and what was expected.
    """

    def __init__(self, path: object, message: str, line: int | None = None) -> None:
        where = f"{path}" if line is None else f"{path}:{line}"
        super().__init__(f"{where}: {message}")
        self.path = path
        self.line = line


class ConfigError(VirtualGPSError):
    """A setting has a wrong value or type; the message names the key and the allowed values."""


class PoseError(VirtualGPSError):
    """A pose message is malformed; ``kind`` groups errors so each kind is logged once."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind
