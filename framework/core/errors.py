"""Exception hierarchy. Every error says what is wrong and, where it can, what to do."""


class SpherecalError(Exception):
    """Base class of every error this package raises on purpose."""


class InputError(SpherecalError, ValueError):
    """Bad input data: NaN, wrong shape, wrong unit, inconsistent station, ..."""


class DegenerateDataError(SpherecalError):
    """The data cannot determine the unknowns. The message says what to add."""


class FitBreakdownError(DegenerateDataError):
    """The fit broke down numerically: the data fit no sphere seen through their poses
    (a setting or the data are wrong, not the noise). The message names the usual causes."""


class DatasetFileError(SpherecalError):
    """A dataset or result file cannot be read; the message names the file and line."""


class ConfigError(SpherecalError):
    """A configuration file or section is invalid; the message names the path."""


class DeviceError(SpherecalError):
    """A robot or sensor failed: timeout, disconnect, protocol error."""


class PluginError(SpherecalError):
    """A plugin failed to load, register or configure; the message names the plugin."""


class FileWriteError(DatasetFileError):
    """An output file could not be written (a full disk, no permission); the message
    names the file."""
