"""Write a :class:`ControlMessage` as canonical XML (docs/design.md §6) and publish the schema
(``control.xsd``).

The output is the paper's shape (``<?xml?>``, root ``<xml>``, one ``<message>``) in a fixed element order,
lengths with an explicit ``unit="m"``, angles with ``unit="deg"``, the paper's spellings for the
straight-line method; :func:`shared.control.parse_message` reads it back to an equal message and it
validates against :func:`xsd_text`. Linear in the message size.
"""

from __future__ import annotations

from importlib import resources
from typing import Any

from lxml import etree

from shared.control.errors import ControlMessageError
from shared.control.model import NO_SCAN_MATCHING, ControlMessage, KernelSpec, ParamValue
from shared.control.vocabulary import (
    CLUSTERING_KERNELS,
    GENERIC_KERNEL,
    KERNEL_NAME,
    LOOP_CLOSURE,
    NOISE_KERNELS,
    SCAN_MATCHERS,
    SEGMENTATION_KERNELS,
    STRAIGHT_LINE_SPELLING,
    KernelElement,
    Kind,
    format_value,
    is_length_param,
)

__all__ = ["build_message", "xsd_schema", "xsd_text"]

_Element = Any  # lxml.etree._Element (lxml ships no type information)


def xsd_text() -> str:
    """The published XML Schema (XSD 1.0) of the control message, from the package data file."""
    return resources.files("shared.control").joinpath("control.xsd").read_text(encoding="utf-8")


def xsd_schema() -> Any:
    """A freshly compiled schema (``lxml.etree.XMLSchema``, ~0.4 ms); ``.validate(tree)`` checks a document.

    Not cached: an lxml validator keeps per-call state (``error_log``), so each caller gets its own.
    """
    return etree.XMLSchema(etree.fromstring(xsd_text().encode("utf-8")))


def build_message(msg: ControlMessage) -> bytes:
    """Canonical UTF-8 XML for ``msg``; :class:`ControlMessageError` if a value cannot be written."""
    root = etree.Element("xml")
    m = etree.SubElement(root, "message")
    if msg.seq is not None:
        _leaf(m, "seq", _integer(msg.seq, "<seq>"))
    if msg.mode is not None:
        _leaf(m, "mode", msg.mode.value)
    if msg.n_smax is not None:
        _leaf(m, "n-smax", _integer(msg.n_smax, "<n-smax>"))
    if msg.heading_flush_deg is not None:
        _leaf(m, "heading-flush", _number(msg.heading_flush_deg, "<heading-flush>"), unit="deg")
    if msg.segmentation is not None:
        _kernel(etree.SubElement(m, "segmentation"), msg.segmentation, SEGMENTATION_KERNELS)
    if msg.noise_removal is not None:
        chain = etree.SubElement(m, "noise-removal")
        for spec in msg.noise_removal:
            _kernel(chain, spec, NOISE_KERNELS)
    if msg.clustering is not None:
        _kernel(etree.SubElement(m, "clustering"), msg.clustering, CLUSTERING_KERNELS)
    if msg.straight_line is not None:
        _method(m, "straight-line-method", msg.straight_line, STRAIGHT_LINE_SPELLING)
    if msg.scan_matching == NO_SCAN_MATCHING:
        _leaf(m, "scan-matching", NO_SCAN_MATCHING)
    elif isinstance(msg.scan_matching, KernelSpec):
        _method(m, "scan-matching", msg.scan_matching, {k: k for k in SCAN_MATCHERS})
    if msg.schedule is not None:
        schedule = etree.SubElement(m, "schedule")
        for entry in msg.schedule:
            stage = etree.SubElement(schedule, "stage", name=entry.stage.value, mode=entry.mode.value)
            if entry.n_smax is not None:
                stage.set("n-smax", _integer(entry.n_smax, "<stage>"))
    if msg.loop_closure is not None:
        if msg.loop_closure.version is not None:
            raise ControlMessageError("loop closure has no versions", element="<loop-closure>")
        _body(etree.SubElement(m, LOOP_CLOSURE.name), msg.loop_closure, LOOP_CLOSURE)
    for op in msg.operations:
        el = etree.SubElement(m, f"kernel-{op.kind.value}", stage=op.stage.value, name=op.name)
        el.set("version", op.version)
        if op.sha256 is not None:
            el.set("sha256", op.sha256)
        if op.below_floor:
            el.set("below-floor", "allow")
    out: bytes = etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)
    return out


def _leaf(parent: _Element, tag: str, text: str, **attrs: str) -> _Element:
    el = etree.SubElement(parent, tag, **attrs)
    try:
        el.text = text
    except ValueError:
        raise ControlMessageError(f"{text!r} holds characters XML cannot carry", element=f"<{tag}>") from None
    return el


def _integer(value: object, element: str) -> str:
    if not isinstance(value, int) or isinstance(value, bool):
        raise ControlMessageError(f"{value!r} is not an integer", element=element)
    return str(value)


def _number(value: object, element: str) -> str:
    if not isinstance(value, int | float) or isinstance(value, bool):
        raise ControlMessageError(f"{value!r} is not a number", element=element)
    try:
        return format_value(value)
    except ValueError as exc:
        raise ControlMessageError(str(exc), element=element) from None


def _generic(parent: _Element, spec: KernelSpec) -> None:
    """``<kernel name="..">`` for a kernel the paper's vocabulary has no element for."""
    if not KERNEL_NAME.fullmatch(spec.name):
        raise ControlMessageError(
            f"{spec.name!r} is not a kernel name: expected lowercase words joined by '-'",
            element=f"<{GENERIC_KERNEL}>",
        )
    _body(etree.SubElement(parent, GENERIC_KERNEL, name=spec.name), spec, KernelElement(spec.name))


def _kernel(parent: _Element, spec: KernelSpec, table: dict[str, KernelElement]) -> None:
    entry = table.get(spec.name)
    if entry is None:
        _generic(parent, spec)
        return
    _body(etree.SubElement(parent, entry.name), spec, entry)


def _method(parent: _Element, tag: str, spec: KernelSpec, spelling: dict[str, str]) -> None:
    """The method's text (the paper's spelling), or one ``<kernel name="..">`` for any other kernel."""
    if spec.name not in spelling:
        _generic(etree.SubElement(parent, tag), spec)
        return
    el = _leaf(parent, tag, spelling[spec.name])
    _body(el, spec, KernelElement(spec.name))


def _body(el: _Element, spec: KernelSpec, entry: KernelElement) -> None:
    if spec.version is not None:
        _leaf(el, "version", spec.version)
    values = spec.params_dict()
    for named in entry.named:
        if named.param in values:
            _named(el, named.element, named.kind, values.pop(named.param))
    for name, value in sorted(values.items()):
        display = f'<param name="{name}">'
        if is_length_param(name):
            _leaf(el, "param", _number(value, display), name=name, unit="m")
            continue
        try:
            _leaf(el, "param", format_value(value), name=name)
        except ValueError as exc:
            raise ControlMessageError(str(exc), element=display) from None


def _named(el: _Element, tag: str, kind: Kind, value: ParamValue) -> None:
    display = f"<{tag}>"
    if kind is Kind.LENGTH:
        _leaf(el, tag, _number(value, display), unit="m")
    elif kind is Kind.INT:
        _leaf(el, tag, _integer(value, display))
    elif kind is Kind.FLOAT:
        _leaf(el, tag, _number(value, display))
    elif kind is Kind.BOOL:
        if not isinstance(value, bool):
            raise ControlMessageError(f"{value!r} is not true or false", element=display)
        _leaf(el, tag, format_value(value))
    elif isinstance(value, str) and value.strip() == value and value:
        _leaf(el, tag, value)
    else:
        raise ControlMessageError(f"{value!r} is not a name", element=display)
