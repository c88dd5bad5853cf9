"""Error types shared by the library and the CLI.

Every error a *user* can cause (a bad file, key, argument or stream) derives from
:class:`UserInputError`; the CLI prints its one-line message and exits with code 2.
Messages name the file or key and the fault, e.g. ``cp.npy: shape (10, 5) but points.npy has 6 points``.
"""

from __future__ import annotations


class VdmAeroError(Exception):
    """Base class of all errors raised on purpose by vdm-aero."""


class UserInputError(VdmAeroError):
    """Bad input from the user: reported as one line, exit code 2, never a traceback."""

    exit_code = 2


class DatasetError(UserInputError):
    """A data set directory that is missing, malformed or inconsistent."""


class SpecError(UserInputError):
    """A simulation spec (YAML) with an unknown, missing or out-of-range key."""


class ModelError(UserInputError):
    """A model artifact that is missing, tampered with or incompatible."""


class NotFittedError(VdmAeroError):
    """An estimator was used before ``fit``: a programming error, not a user error."""


class VehicleError(UserInputError):
    """A nominal vehicle description that is missing, malformed or out of range."""
