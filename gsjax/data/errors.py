"""What the readers raise and warn: a dataset that cannot be used, and what is handled but worth knowing."""

from __future__ import annotations


class DatasetError(ValueError):
    """A dataset on disk is missing, malformed or inconsistent; the message names the file and the problem."""


class DatasetWarning(UserWarning):
    """Something in a dataset that gsjax handles in a defined way (a sorted list, a frame left out of the
    evaluation, ...) but the user should know about; the message names the file (and frame) and what was done."""
