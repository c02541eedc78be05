"""One exception hierarchy; the CLI turns every ``KinadaptError`` into one line, exit 2."""


class KinadaptError(Exception):
    """Base class of every error the package raises on purpose."""


class ConfigError(KinadaptError):
    """A configuration value, key or file is wrong (message says what and how to fix it)."""


class ModelFileError(KinadaptError):
    """A model (MJCF) or checkpoint file is missing or unreadable."""


class OutputExistsError(KinadaptError):
    """The output folder exists and ``--overwrite`` was not given."""


class SensorError(KinadaptError):
    """A sensor sample is not finite (NaN or inf) or has the wrong shape."""
