"""User-facing errors.

Every problem caused by the user's input or flags raises a subclass of :class:`UserError`
(itself a ``ValueError``). The CLI turns it into exit code 2 and one line on stderr; anything
else is an internal error (exit code 1).
"""


class UserError(ValueError):
    """Bad input or usage; the message is one line a user can act on."""


class InputFileError(UserError):
    """A file could not be read or is malformed. The message names the file."""

    def __init__(self, path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class ParameterError(UserError):
    """An argument is out of range or of the wrong shape; says which argument and what was received."""

    def __init__(self, name: str, expected: str, received):
        self.name, self.expected, self.received = name, expected, received
        super().__init__(f"{name}: expected {expected}, got {received!r}")
