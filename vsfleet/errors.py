"""Typed errors raised by the pure core. All subclass ValueError."""


class VsfleetValueError(ValueError):
    """Base class for every bad-input error raised by vsfleet."""


class ShapeError(VsfleetValueError):
    """An array argument has the wrong shape or the arrays disagree in length."""


class NonFiniteError(VsfleetValueError):
    """An argument holds NaN or infinity."""


class UnknownMetricError(VsfleetValueError):
    """The metric is not one of 'l1', 'l2', 'linf'."""


class WeightError(VsfleetValueError):
    """Weights are negative, or all zero."""


class EnvelopeError(VsfleetValueError):
    """A kinematic envelope has a non-positive or non-finite limit."""
