"""The control message's vocabulary (docs/design.md §6): element names, kernel names, units and value
spellings.

Paper elements (Listing 1) and their kernels:

=====================  ==============================================================================
``<noise-removal>``    any of ``<dbscan>{<minpts>, <epsilon>}``, ``<erosion>``, ``<dilation>``,
                       ``<opening>`` ``{<kernel-name>}``, in order (kernels ``dbscan``, ``erosion``, ...)
``<clustering>``       ``<kmeans>{<cluster-no>}`` or ``<fcm>{<cluster-no>, <fuzzifier>, <tolerance>,
                       <max-iterations>}``
``<straight-line-method>``  Hough | SVD | CentroidJoin | HoughCluster (any case; also the kernel names)
=====================  ==============================================================================

Any other kernel, built in or installed from the server, is named in its stage's element by
``<kernel name="radius-outlier">`` holding ``<version>`` and ``<param name="..">`` elements (inside
``<straight-line-method>`` and ``<scan-matching>`` in place of the method's text): the vocabulary of kernels
is whatever the registry and the robot's kernel store hold, and only the paper's own elements are listed
here. Which names exist is checked where the kernels are known (:func:`shared.control.to_config` builds
each one; the server checks against the robot's reported store).

Lengths are centimetres unless the element carries ``unit="m|cm|mm"``; a generic ``<param name=".."/>`` is a
length iff its name ends in ``_m`` (the project's naming rule). Value lexing here is pure and raises
``ValueError`` with the reason alone; the parser adds the element and line.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from enum import StrEnum

from shared.control.model import ParamValue
from shared.kernels import Stage
from shared.protocol.patterns import KERNEL_NAME_RE, SHA256_RE

__all__ = [
    "ANGLE_UNITS",
    "CLUSTERING_KERNELS",
    "DEFAULT_ANGLE_UNIT",
    "DEFAULT_LENGTH_UNIT",
    "GENERIC_KERNEL",
    "KERNEL_NAME",
    "LENGTH_UNITS",
    "LOOP_CLOSURE",
    "MAX_INT",
    "NOISE_KERNELS",
    "PARAM_NAME",
    "SCAN_MATCHERS",
    "SEGMENTATION_KERNELS",
    "SHA256",
    "STRAIGHT_LINE_METHODS",
    "STRAIGHT_LINE_SPELLING",
    "KernelElement",
    "Kind",
    "NamedParam",
    "format_value",
    "is_length_param",
    "kernel_element",
    "lex_value",
    "param_element",
    "parse_bool",
    "parse_float",
    "parse_int",
    "scale_angle",
    "scale_length",
]

#: Divisor turning a length in each unit into metres.
LENGTH_UNITS: dict[str, float] = {"m": 1.0, "cm": 100.0, "mm": 1000.0}
DEFAULT_LENGTH_UNIT = "cm"
#: Factor turning an angle in each unit into degrees.
ANGLE_UNITS: dict[str, float] = {"deg": 1.0, "rad": 180.0 / math.pi}
DEFAULT_ANGLE_UNIT = "deg"

#: Largest magnitude of an integer value (fits a signed 64-bit column).
MAX_INT = 2**63 - 1

#: Kernel names and digests are spelled as the protocol spells them (use ``fullmatch``).
KERNEL_NAME = KERNEL_NAME_RE
SHA256 = SHA256_RE
PARAM_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_INT = re.compile(r"^[+-]?[0-9]+$")
_FLOAT = re.compile(r"^[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?$")


class Kind(StrEnum):
    """How a named parameter element's text is read."""

    INT = "integer"
    FLOAT = "number"
    LENGTH = "length"
    TEXT = "text"
    BOOL = "true or false"


@dataclass(frozen=True, slots=True)
class NamedParam:
    """A paper-style parameter element (``<minpts>``) standing for kernel parameter ``param``."""

    element: str
    param: str
    kind: Kind


@dataclass(frozen=True, slots=True)
class KernelElement:
    """A kernel element; its XML name is the registry name. ``named`` lists its parameter elements."""

    name: str
    named: tuple[NamedParam, ...] = ()

    def by_element(self, element: str) -> NamedParam | None:
        """The named parameter spelled ``element``, if any."""
        return next((p for p in self.named if p.element == element), None)

    def by_param(self, param: str) -> NamedParam | None:
        """The named parameter element for kernel parameter ``param``, if any."""
        return next((p for p in self.named if p.param == param), None)


_MORPH = (NamedParam("kernel-name", "element", Kind.TEXT),)
_CLUSTER_NO = NamedParam("cluster-no", "n_clusters", Kind.INT)

NOISE_KERNELS: dict[str, KernelElement] = {
    "dbscan": KernelElement(
        "dbscan",
        (NamedParam("minpts", "min_points", Kind.INT), NamedParam("epsilon", "epsilon_m", Kind.LENGTH)),
    ),
    "erosion": KernelElement("erosion", _MORPH),
    "dilation": KernelElement("dilation", _MORPH),
    "opening": KernelElement("opening", _MORPH),
}
CLUSTERING_KERNELS: dict[str, KernelElement] = {
    "kmeans": KernelElement("kmeans", (_CLUSTER_NO,)),
    "fcm": KernelElement(
        "fcm",
        (
            _CLUSTER_NO,
            NamedParam("fuzzifier", "fuzzifier", Kind.FLOAT),
            NamedParam("tolerance", "tolerance", Kind.FLOAT),
            NamedParam("max-iterations", "max_iterations", Kind.INT),
        ),
    ),
}
SEGMENTATION_KERNELS: dict[str, KernelElement] = {"abd-iepf": KernelElement("abd-iepf")}

#: ``<straight-line-method>`` text, lower-cased, -> straight-line kernel.
STRAIGHT_LINE_METHODS: dict[str, str] = {
    "hough": "hough",
    "svd": "svd",
    "centroidjoin": "centroid-join",
    "centroid-join": "centroid-join",
    "houghcluster": "hough-cluster",
    "hough-cluster": "hough-cluster",
}
#: The paper's spelling of each straight-line kernel (what the builder writes).
STRAIGHT_LINE_SPELLING: dict[str, str] = {
    "hough": "Hough",
    "svd": "SVD",
    "centroid-join": "CentroidJoin",
    "hough-cluster": "HoughCluster",
}
#: ``<loop-closure>``: loop closure under a keyframe pose graph, stated whole (what it leaves out takes
#: :class:`shared.slam.settings.LoopClosureSettings`' defaults); any other setting by ``<param name="..">``.
LOOP_CLOSURE = KernelElement(
    "loop-closure",
    (
        NamedParam("enabled", "enabled", Kind.BOOL),
        NamedParam("search-radius", "search_radius_m", Kind.LENGTH),
        NamedParam("min-inlier-share", "min_inlier_share", Kind.FLOAT),
    ),
)

#: ``<scan-matching>`` text, lower-cased, -> scan-matching kernel (``none`` switches it off).
SCAN_MATCHERS: dict[str, str] = {"icp": "icp", "icp-line": "icp-line"}

_STAGE_KERNELS: dict[Stage, dict[str, KernelElement]] = {
    Stage.SEGMENTATION: SEGMENTATION_KERNELS,
    Stage.NOISE_REMOVAL: NOISE_KERNELS,
    Stage.CLUSTERING: CLUSTERING_KERNELS,
    Stage.STRAIGHT_LINE: {k: KernelElement(k) for k in STRAIGHT_LINE_SPELLING},
    Stage.SCAN_MATCHING: {k: KernelElement(k) for k in SCAN_MATCHERS},
}


#: The element that names any kernel by its registry name: ``<kernel name="radius-outlier">``.
GENERIC_KERNEL = "kernel"


def kernel_element(stage: Stage, kernel: str) -> KernelElement | None:
    """The paper's element for ``kernel`` in ``stage`` (``<dbscan>``, ``Hough``), or ``None`` when the kernel
    has none and is named by ``<kernel name="..">``."""
    return _STAGE_KERNELS[stage].get(kernel)


def param_element(stage: Stage, kernel: str, param: str) -> str:
    """Display name of the element that carries ``param`` of ``kernel`` (``"<epsilon>"``)."""
    entry = kernel_element(stage, kernel)
    named = entry.by_param(param) if entry is not None else None
    return f"<{named.element}>" if named is not None else f'<param name="{param}">'


def is_length_param(name: str) -> bool:
    """Whether a generic parameter is a length (its name ends in ``_m``), read with a unit."""
    return name.endswith("_m")


def parse_int(text: str) -> int:
    """Decimal integer (sign allowed, |value| <= 2**63 - 1)."""
    if not _INT.match(text):
        raise ValueError(f"{text!r} is not an integer")
    value = int(text)
    if abs(value) > MAX_INT:
        raise ValueError(f"{text!r} is out of range: expected |value| <= {MAX_INT}")
    return value


def parse_float(text: str) -> float:
    """Finite decimal number (``5``, ``0.05``, ``5e-2``); no ``inf``, ``nan`` or ``_`` separators."""
    if not _FLOAT.match(text):
        raise ValueError(f"{text!r} is not a number")
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text!r} is out of range: expected a finite number")
    return value


def parse_bool(text: str) -> bool:
    """``true``/``on``/``1`` or ``false``/``off``/``0``, any case."""
    key = text.lower()
    if key in ("true", "on", "1"):
        return True
    if key in ("false", "off", "0"):
        return False
    raise ValueError(f"{text!r} is not a switch: expected true or false (on/off, 1/0)")


def scale_length(value: float, unit: str | None) -> float:
    """``value`` in ``unit`` (default centimetres) as metres."""
    unit = DEFAULT_LENGTH_UNIT if unit is None else unit
    if unit not in LENGTH_UNITS:
        raise ValueError(f"unit {unit!r} is not a length unit: expected one of {', '.join(LENGTH_UNITS)}")
    return value / LENGTH_UNITS[unit]


def scale_angle(value: float, unit: str | None) -> float:
    """``value`` in ``unit`` (default degrees) as degrees."""
    unit = DEFAULT_ANGLE_UNIT if unit is None else unit
    if unit not in ANGLE_UNITS:
        raise ValueError(f"unit {unit!r} is not an angle unit: expected one of {', '.join(ANGLE_UNITS)}")
    return value * ANGLE_UNITS[unit]


def lex_value(text: str) -> ParamValue:
    """A generic ``<param>`` value by its spelling: integer, number, ``true``/``false``, a list of two or more
    whitespace-separated integers (a tuple, e.g. a psi vector ``1 1 0``), else the text itself."""
    if _INT.match(text):
        return parse_int(text)
    if _FLOAT.match(text):
        return parse_float(text)
    if text in ("true", "false"):
        return text == "true"
    tokens = text.split()
    if len(tokens) >= 2 and all(_INT.match(t) for t in tokens):
        return tuple(parse_int(t) for t in tokens)
    return text


def format_value(value: ParamValue) -> str:
    """The spelling :func:`lex_value` reads back as ``value``; ``ValueError`` if there is none."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"{value!r} is not a finite number")
        return repr(value)
    if isinstance(value, tuple):
        if len(value) < 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise ValueError(f"{value!r} cannot be written: a list value needs two or more integers")
        return " ".join(str(v) for v in value)
    if isinstance(value, str) and value and value == value.strip() and type(lex_value(value)) is str:
        return value
    raise ValueError(f"{value!r} cannot be written so that it reads back the same")
