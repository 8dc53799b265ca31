"""Errors raised by the baselines (:mod:`shared.baselines`)."""

from __future__ import annotations

import math

from shared.errors import InvalidInputError, LinemapError

__all__ = ["BaselineError", "BaselineParameterError", "check_number"]


class BaselineError(LinemapError):
    """A baseline cannot run on the data or settings given."""


class BaselineParameterError(BaselineError, InvalidInputError):
    """A baseline setting is out of range. ``owner`` is the settings class, ``parameter`` the field."""

    def __init__(self, owner: str, parameter: str, value: object, expected: str) -> None:
        self.owner = owner
        self.parameter = parameter
        self.value = value
        super().__init__(f"{owner}.{parameter} = {value!r}: expected {expected}")


def check_number(
    owner: str,
    name: str,
    value: object,
    *,
    minimum: float = 0.0,
    inclusive: bool = False,
    maximum: float = math.inf,
    integer: bool = False,
) -> None:
    """Raise :class:`BaselineParameterError` unless ``value`` is a finite number in the allowed range.

    The range is ``minimum < value <= maximum`` (``minimum <= value`` with ``inclusive``); ``integer``
    also asks for an ``int``. Booleans are refused. O(1).
    """
    kind = "an integer" if integer else "a finite number"
    low = f">= {minimum:g}" if inclusive else f"> {minimum:g}"
    expected = f"{kind} {low}" + (f" and <= {maximum:g}" if math.isfinite(maximum) else "")
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or (integer and not isinstance(value, int))
    ):
        raise BaselineParameterError(owner, name, value, expected)
    v = float(value)
    in_range = (v >= minimum if inclusive else v > minimum) and v <= maximum
    if not (math.isfinite(v) and in_range):
        raise BaselineParameterError(owner, name, value, expected)
