"""Parse a control message (docs/design.md §6, the paper's Listing 1) into a :class:`ControlMessage`,
hardened.

The document is loaded by :func:`shared.control.safe_xml.load_xml` (size limit, UTF-8, no DTD, no
entities, no network); comments and processing instructions are ignored. The walk is strict: an unknown
element, attribute or stray text, a repeated element, or a bad value rejects the whole message with a
:class:`ControlMessageError` naming the element, its line and the reason. Linear in the input size.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from typing import Any, Literal, NoReturn, TypeVar

from shared.control.errors import ControlMessageError
from shared.control.model import (
    NO_SCAN_MATCHING,
    ControlMessage,
    KernelOperation,
    KernelSpec,
    OperationKind,
    ParamValue,
    ScheduleEntry,
)
from shared.control.safe_xml import MAX_MESSAGE_BYTES, load_xml
from shared.control.vocabulary import (
    CLUSTERING_KERNELS,
    GENERIC_KERNEL,
    KERNEL_NAME,
    LOOP_CLOSURE,
    NOISE_KERNELS,
    PARAM_NAME,
    SCAN_MATCHERS,
    SEGMENTATION_KERNELS,
    SHA256,
    STRAIGHT_LINE_METHODS,
    KernelElement,
    Kind,
    is_length_param,
    lex_value,
    parse_bool,
    parse_float,
    parse_int,
    scale_angle,
    scale_length,
)
from shared.kernels import Stage
from shared.kernels.versions import parse_version
from shared.pipeline.config import SCHEDULED, Mode

__all__ = ["BELOW_FLOOR", "MAX_MESSAGE_BYTES", "parse_message"]

#: The attribute of ``<kernel-rollback>`` that overrides the anti-rollback floor (value ``allow``).
BELOW_FLOOR = "below-floor"

_log = logging.getLogger(__name__)

T = TypeVar("T")
_Element = Any  # lxml.etree._Element (lxml ships no type information)

_OPERATIONS = {f"kernel-{kind.value}": kind for kind in OperationKind}


def parse_message(data: bytes | str) -> ControlMessage:
    """Parse and validate one control message; raise :class:`ControlMessageError` on anything wrong."""
    root = load_xml(data)
    if root.tag != "xml":
        _fail(root, "wrong root element: expected <xml> holding one <message> (the paper's Listing 1)")
    _attributes(root, ())
    messages = _elements(root)
    if not messages:
        _fail(root, "holds no <message>: expected exactly one")
    for child in messages:
        if child.tag != "message":
            _unknown(child, root, ["message"])
    if len(messages) > 1:
        _fail(messages[1], f"a second <message> (first on line {messages[0].sourceline}): expected one")
    message = _message(messages[0])
    _log.debug("parsed control message seq=%s", message.seq)
    return message


# ------------------------------------------------------------------------------------------- structure


def _display(el: _Element) -> str:
    """``<tag>`` or ``<param name="...">``, cut to 60 characters (names in errors stay short)."""
    name = el.get("name") if el.tag == "param" else None
    text = f'<param name="{name}">' if name else f"<{el.tag}>"
    return text if len(text) <= 60 else text[:56] + "...>"


def _fail(el: _Element, reason: str) -> NoReturn:
    raise ControlMessageError(reason, element=_display(el), line=el.sourceline)


def _unknown(child: _Element, parent: _Element, allowed: list[str]) -> NoReturn:
    expected = ", ".join(f"<{a}>" for a in allowed) or "no elements"
    _fail(child, f"unknown element in <{parent.tag}>: expected {expected}")


def _check_node(child: _Element, parent: _Element) -> None:
    if not isinstance(child.tag, str):  # an entity reference left unexpanded
        raise ControlMessageError(
            f"entity reference {child!s} is not allowed", element=f"<{parent.tag}>", line=parent.sourceline
        )


def _elements(el: _Element) -> list[_Element]:
    """Child elements of an element that holds elements only (stray text is an error)."""
    out: list[_Element] = []
    for text in [el.text, *(child.tail for child in el)]:
        if text and text.strip():
            _fail(el, f"unexpected text {text.strip()[:40]!r}: <{el.tag}> holds elements only")
    for child in el:
        _check_node(child, el)
        out.append(child)
    return out


def _attributes(el: _Element, allowed: tuple[str, ...]) -> dict[str, str]:
    attrs = {str(k): str(v).strip() for k, v in el.attrib.items()}
    for key in attrs:
        if key not in allowed:
            expected = ", ".join(allowed) if allowed else "none"
            _fail(el, f"unknown attribute {key!r}: expected {expected}")
    return attrs


def _no_content(el: _Element) -> None:
    """``el`` carries attributes only: no text, no child elements."""
    for child in el:
        _check_node(child, el)
        _fail(child, f"unexpected element inside <{el.tag}>, which holds attributes only")
    if el.text and el.text.strip():
        _fail(el, f"unexpected text {el.text.strip()[:40]!r}: <{el.tag}> holds attributes only")


def _leaf(el: _Element, expected: str, allowed: tuple[str, ...] = ()) -> str:
    """The stripped text of an element that holds one value."""
    _attributes(el, allowed)
    for child in el:
        _check_node(child, el)
        _fail(child, f"unexpected element inside <{el.tag}>, which holds {expected}")
    text = (el.text or "").strip()
    if not text:
        _fail(el, f"is empty: expected {expected}")
    return str(text)


def _read(el: _Element, text: str, convert: Callable[[str], T]) -> T:
    try:
        return convert(text)
    except ValueError as exc:
        _fail(el, str(exc))


def _value(el: _Element, convert: Callable[[str], T], expected: str) -> T:
    return _read(el, _leaf(el, expected), convert)


def _measure(el: _Element, scale: Callable[[float, str | None], float]) -> float:
    attrs = _attributes(el, ("unit",))
    text = _leaf(el, "a number", ("unit",))
    return _read(el, text, lambda t: scale(parse_float(t), attrs.get("unit")))


# -------------------------------------------------------------------------------------------- message


def _message(el: _Element) -> ControlMessage:
    _attributes(el, ())
    fields: dict[str, Any] = {}
    seen: dict[str, int] = {}
    operations: list[KernelOperation] = []
    for child in _elements(el):
        if child.tag in _OPERATIONS:
            operations.append(_operation(child, _OPERATIONS[child.tag]))
            continue
        entry = _TOP.get(child.tag)
        if entry is None:
            _unknown(child, el, [*_TOP, *_OPERATIONS])
        if child.tag in seen:
            _fail(child, f"given twice (first on line {seen[child.tag]})")
        seen[child.tag] = child.sourceline
        field, read = entry
        fields[field] = read(child)
    return ControlMessage(**fields, operations=tuple(operations), lines=tuple(seen.items()))


def _seq(el: _Element) -> int:
    value = _value(el, parse_int, "a message sequence number")
    if value < 0:
        _fail(el, f"{value} is negative: expected a sequence number >= 0")
    return value


def _mode_of(text: str) -> Mode:
    try:
        return Mode(text.lower())
    except ValueError:
        raise ValueError(f"{text!r} is not a mode: expected online, offline or mixed") from None


def _kernel_body(el: _Element, entry: KernelElement, children: list[_Element]) -> KernelSpec:
    params: dict[str, ParamValue] = {}
    where: dict[str, int] = {}
    version: str | None = None
    version_line = 0
    for child in children:
        named = entry.by_element(child.tag)
        if child.tag == "version":
            if version is not None:
                _fail(child, f"given twice (first on line {version_line})")
            version, version_line = _value(child, _version, "a version MAJOR.MINOR.PATCH"), child.sourceline
            continue
        if child.tag == "param":
            name, value = _param(child)
        elif named is not None:
            name, value = named.param, _named_value(child, named.kind)
        else:
            _unknown(child, el, [*(p.element for p in entry.named), "param", "version"])
        if name in params:
            _fail(child, f"parameter {name!r} given twice (first on line {where[name]})")
        params[name], where[name] = value, child.sourceline
    return KernelSpec(
        entry.name, tuple(params.items()), version, line=el.sourceline, param_lines=tuple(where.items())
    )


def _version(text: str) -> str:
    parse_version(text)
    return text


def _named_value(el: _Element, kind: Kind) -> ParamValue:
    if kind is Kind.LENGTH:
        return _measure(el, scale_length)
    if kind is Kind.INT:
        return _value(el, parse_int, "an integer")
    if kind is Kind.FLOAT:
        return _value(el, parse_float, "a number")
    if kind is Kind.BOOL:
        return _value(el, parse_bool, "true or false")
    return _leaf(el, "a name")


def _param(el: _Element) -> tuple[str, ParamValue]:
    attrs = _attributes(el, ("name", "unit"))
    name = attrs.get("name", "")
    if not PARAM_NAME.match(name):
        _fail(el, f"name {name!r} is not a parameter name: expected letters, digits and '_'")
    text = _leaf(el, "a value", ("name", "unit"))
    if is_length_param(name):
        return name, _read(el, text, lambda t: scale_length(parse_float(t), attrs.get("unit")))
    if "unit" in attrs:
        _fail(el, f"unit applies only to lengths (parameter names ending in _m), not to {name!r}")
    return name, lex_value(text)


def _generic(el: _Element) -> KernelSpec:
    """``<kernel name="..">``: any kernel by its registry name, parameters by ``<param>`` only."""
    name = _attributes(el, ("name",)).get("name", "")
    if not KERNEL_NAME.fullmatch(name):
        _fail(
            el,
            f"name={name[:40]!r} is not a kernel name: expected lowercase words joined by '-' "
            "(e.g. radius-outlier)",
        )
    return _kernel_body(el, KernelElement(name), _elements(el))


def _kernels(el: _Element, table: Mapping[str, KernelElement]) -> list[KernelSpec]:
    _attributes(el, ())
    specs: list[KernelSpec] = []
    for child in _elements(el):
        if child.tag == GENERIC_KERNEL:
            specs.append(_generic(child))
            continue
        entry = table.get(child.tag)
        if entry is None:
            _unknown(child, el, [*table, f'{GENERIC_KERNEL} name=".."'])
        _attributes(child, ())
        specs.append(_kernel_body(child, entry, _elements(child)))
    return specs


def _one_kernel(el: _Element, table: Mapping[str, KernelElement]) -> KernelSpec:
    specs = _kernels(el, table)
    if not specs:
        expected = ", ".join(f"<{k}>" for k in table)
        _fail(el, f'is empty: expected one of {expected} or <{GENERIC_KERNEL} name="..">')
    if len(specs) > 1:
        _fail(_elements(el)[1], f"a second kernel: <{el.tag}> takes exactly one")
    return specs[0]


def _method(el: _Element, table: Mapping[str, str], expected: str, allow_none: bool) -> Any:
    _attributes(el, ())
    children = list(el)
    for child in children:
        _check_node(child, el)
    text = "".join([el.text or "", *(child.tail or "" for child in children)]).strip()
    generic = [child for child in children if child.tag == GENERIC_KERNEL]
    if generic:
        if text or len(children) > 1:
            _fail(
                generic[0],
                f"<{el.tag}> names its kernel either by its text or by one <{GENERIC_KERNEL}> "
                "element (holding the parameters), not both",
            )
        return _generic(generic[0])
    if not text:
        _fail(el, f'is empty: expected {expected}, or <{GENERIC_KERNEL} name=".."> for any other kernel')
    key = text.lower()
    if allow_none and key == "none":
        if children:
            _fail(children[0], f"<{el.tag}>none takes no parameters")
        return NO_SCAN_MATCHING
    kernel = table.get(key)
    if kernel is None:
        _fail(
            el,
            f"{text!r} is not a known method: expected {expected} (any case), "
            f'or <{GENERIC_KERNEL} name=".."> for any other kernel',
        )
    return _kernel_body(el, KernelElement(kernel), children)


def _straight_line(el: _Element) -> KernelSpec:
    spec: KernelSpec = _method(el, STRAIGHT_LINE_METHODS, "Hough, SVD, CentroidJoin or HoughCluster", False)
    return spec


def _scan_matching(el: _Element) -> KernelSpec | Literal["none"]:
    spec: KernelSpec | Literal["none"] = _method(el, SCAN_MATCHERS, "icp, icp-line or none", True)
    return spec


def _loop_closure(el: _Element) -> KernelSpec:
    _attributes(el, ())
    children = _elements(el)
    for child in children:
        if child.tag == "version":
            _fail(
                child,
                "<loop-closure> has no versions: expected <enabled>, <search-radius>, "
                "<min-inlier-share> or <param>",
            )
    return _kernel_body(el, LOOP_CLOSURE, children)


def _schedule(el: _Element) -> tuple[ScheduleEntry, ...]:
    _attributes(el, ())
    entries: dict[Stage, ScheduleEntry] = {}
    allowed = ", ".join(SCHEDULED)
    for child in _elements(el):
        if child.tag != "stage":
            _unknown(child, el, ["stage"])
        attrs = _attributes(child, ("name", "mode", "n-smax"))
        _no_content(child)
        for key in ("name", "mode"):
            if key not in attrs:
                _fail(child, f"needs a {key} attribute")
        stage = next((s for s in SCHEDULED if s.value == attrs["name"]), None)
        if stage is None:
            _fail(child, f"name={attrs['name']!r} is not a stage that can be scheduled: expected {allowed}")
        mode = _read(child, attrs["mode"], _mode_of)
        if mode is Mode.MIXED:
            _fail(child, "mode='mixed' is for the whole message: a stage runs online or offline")
        n_smax = _read(child, attrs["n-smax"], parse_int) if "n-smax" in attrs else None
        if stage in entries:
            _fail(child, f"stage {stage.value!r} given twice (first on line {entries[stage].line})")
        entries[stage] = ScheduleEntry(stage, mode, n_smax, line=child.sourceline)
    return tuple(entries.values())


def _operation(el: _Element, kind: OperationKind) -> KernelOperation:
    names = ("stage", "name", "version", "sha256")
    attrs = _attributes(el, (*names, BELOW_FLOOR) if kind is OperationKind.ROLLBACK else names)
    _no_content(el)
    required = ["stage", "name", "version"]
    if kind in (OperationKind.INSTALL, OperationKind.UPDATE):
        required.append("sha256")
    for key in required:
        if key not in attrs:
            _fail(el, f"needs a {key} attribute")
    stage = next((s for s in Stage if s.value == attrs["stage"]), None)
    if stage is None:
        _fail(el, f"stage={attrs['stage']!r} is not a stage: expected {', '.join(Stage)}")
    if not KERNEL_NAME.fullmatch(attrs["name"]):
        _fail(el, f"name={attrs['name']!r} is not a kernel name: expected lower-case words joined by '-'")
    _read(el, attrs["version"], _version)
    sha = attrs.get("sha256")
    if sha is not None and not SHA256.fullmatch(sha):
        _fail(el, f"sha256={sha[:70]!r} is not a SHA-256 digest: expected 64 hexadecimal digits")
    digest = sha.lower() if sha is not None else None
    below = attrs.get(BELOW_FLOOR)
    if below is not None and below != "allow":
        _fail(el, f'{BELOW_FLOOR}={below[:40]!r}: expected {BELOW_FLOOR}="allow" (or no such attribute)')
    return KernelOperation(
        kind,
        stage,
        attrs["name"],
        attrs["version"],
        digest,
        line=el.sourceline,
        below_floor=below is not None,
    )


#: Top-level elements of ``<message>``: element -> (ControlMessage field, reader).
_TOP: dict[str, tuple[str, Callable[[_Element], Any]]] = {
    "seq": ("seq", _seq),
    "mode": ("mode", lambda el: _value(el, _mode_of, "online, offline or mixed")),
    "n-smax": ("n_smax", lambda el: _value(el, parse_int, "an integer")),
    "heading-flush": ("heading_flush_deg", lambda el: _measure(el, scale_angle)),
    "segmentation": ("segmentation", lambda el: _one_kernel(el, SEGMENTATION_KERNELS)),
    "noise-removal": ("noise_removal", lambda el: tuple(_kernels(el, NOISE_KERNELS))),
    "clustering": ("clustering", lambda el: _one_kernel(el, CLUSTERING_KERNELS)),
    "straight-line-method": ("straight_line", _straight_line),
    "scan-matching": ("scan_matching", _scan_matching),
    "schedule": ("schedule", _schedule),
    "loop-closure": ("loop_closure", _loop_closure),
}
