"""The package's one documented error type and its kinds.

Every problem with a user's input (config, model spec, data, command-line options) raises a
subclass of :class:`MSAMError` whose message names the offending place: a config key path such
as ``model.equations[0].components[1].theta``, an option such as ``--out``, or a file with its
column and row. ``exit_status`` is what ``msam`` exits with: 2 for bad input, 3 for a record that
tells nothing for a target or a run that finished without learning anything (its result is still
written and records why), 130 for a run stopped by Ctrl-C (its best state so far written).
"""


class MSAMError(Exception):
    """Base class of every error msam-torch raises on bad input."""

    exit_status = 2


class ConfigError(MSAMError):
    """A config, model spec or option is malformed; the message starts with the key path."""

    def __init__(self, key: str, message: str):
        self.key = key
        shown = key if key.isprintable() else ascii(key)  # a key typed with line breaks stays on one line
        super().__init__(f"{shown}: {message}" if key else message)


class DataError(MSAMError):
    """Measured data are unusable; the message names the file, column and rows."""


class Uninformative(DataError):
    """A record tells nothing for a target: it is constant up to rounding, or, estimated from the
    data, to the precision of the estimate. Found before fitting: nothing is written; found by the
    diagnosis that closes a run: :class:`NoInformation` (the run's result is written)."""

    exit_status = 3


class NoInformation(MSAMError):
    """The run ended but its result carries no information (every candidate diverged, or the
    fitted values are not finite); the result file records it."""

    exit_status = 3


class Interrupted(MSAMError):
    """Ctrl-C ended the adaptation early; the best state found so far is written."""

    exit_status = 130
