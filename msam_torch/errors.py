"""The package's one documented error type and its kinds.

Every problem with a user's input (config, model spec, data) raises a subclass of
:class:`MSAMError` whose message names the offending place: a config key path such as
``model.equations[0].components[1].theta``, or a file with its column and row.
"""


class MSAMError(Exception):
    """Base class of every error msam-torch raises on bad input."""


class ConfigError(MSAMError):
    """A config or model spec is malformed; the message starts with the key path."""

    def __init__(self, key: str, message: str):
        self.key = key
        super().__init__(f"{key}: {message}" if key else message)


class DataError(MSAMError):
    """Measured data are unusable; the message names the file, column and rows."""
