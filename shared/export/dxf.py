"""The map as a DXF drawing (AutoCAD R2013, UTF-8, units metres), and reading it back.

Layout: one ``LINE`` per wall on layer ``walls`` (blue), its segment id in XDATA of the application
``LINEMAP`` (group code 1071); one ``POINT`` per cluster centroid on layer ``centroids`` (orange); the
trajectory as one ``LWPOLYLINE`` on layer ``trajectory`` (green), when it has two or more poses. The header
says ``$INSUNITS = 6`` (metres) and ``$MEASUREMENT = 1`` (metric). Coordinates are the world frame's x and
y in metres, z = 0; ezdxf writes floats with Python's shortest round-trip repr, so a round trip is exact.

The reader takes any DXF: the ``LINE`` entities of layer ``walls`` (layer names are case-insensitive in
DXF), scaled to metres from the file's ``$INSUNITS`` (unitless files are taken as metres). ezdxf is
imported on first use. O(L + C + T). docs/design.md §1 (the operator exports the finished map), §3 (metres,
REP 103 frame).
"""

from __future__ import annotations

import io
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from shared.export.atomic import atomic_write_bytes
from shared.export.errors import DXFFormatError, ExportIOError
from shared.export.validate import check_snapshot
from shared.pipeline.snapshot import MapSnapshot
from shared.types import FloatArray, IntArray

if TYPE_CHECKING:
    from ezdxf.document import Drawing
    from ezdxf.entities.dxfentity import DXFEntity

__all__ = ["DXF_APPID", "DXF_LAYERS", "DXFMap", "encode_dxf", "read_dxf", "write_dxf"]

_log = logging.getLogger(__name__)

DXF_APPID = "LINEMAP"
"""XDATA application name under which each wall ``LINE`` carries its segment id."""

DXF_LAYERS = {"walls": 5, "centroids": 30, "trajectory": 3}
"""Layer name -> AutoCAD colour index (5 blue, 30 orange, 3 green)."""

_INSUNITS_METRES = 6
# $INSUNITS code -> metres per drawing unit (exact definitions; 0 = unitless, taken as metres)
_METRES_PER_UNIT = {
    0: 1.0,
    1: 0.0254,  # inch
    2: 0.3048,  # foot
    3: 1609.344,  # mile
    4: 1e-3,  # millimetre
    5: 1e-2,  # centimetre
    6: 1.0,  # metre
    7: 1e3,  # kilometre
    10: 0.9144,  # yard
    11: 1e-10,  # angstrom
    12: 1e-9,  # nanometre
    13: 1e-6,  # micron
    14: 0.1,  # decimetre
    15: 10.0,  # decametre
    16: 100.0,  # hectometre
}
_XDATA_ID = 1071  # 32-bit signed integer
_ID_RANGE = (-(2**31), 2**31 - 1)


@dataclass(frozen=True, slots=True, eq=False)
class DXFMap:
    """What :func:`read_dxf` found, in metres: ``segments`` ``(L, 4)`` ``[x0, y0, x1, y1]`` in file order
    with ``segment_ids`` ``(L,)`` (-1 for a line without linemap XDATA), ``centroids`` ``(C, 2)`` and the
    ``trajectory`` vertices ``(T, 2)`` (x, y; the DXF holds no stamps or headings)."""

    segments: FloatArray
    segment_ids: IntArray
    centroids: FloatArray
    trajectory: FloatArray


def _drawing(snapshot: MapSnapshot) -> Drawing:
    from ezdxf.filemanagement import new

    checked = check_snapshot(snapshot)
    ids = checked.segment_ids
    if ids.size and (int(ids.min()) < _ID_RANGE[0] or int(ids.max()) > _ID_RANGE[1]):
        from shared.errors import InvalidInputError

        raise InvalidInputError(
            f"snapshot.segment_ids span {int(ids.min())}..{int(ids.max())}: expected 32-bit integers for DXF"
        )
    doc = new("R2013", setup=False)
    doc.header["$INSUNITS"] = _INSUNITS_METRES
    doc.header["$MEASUREMENT"] = 1
    doc.appids.add(DXF_APPID)
    for name, colour in DXF_LAYERS.items():
        doc.layers.add(name, color=colour)
    msp = doc.modelspace()
    for (x0, y0, x1, y1), seg_id in zip(checked.segments.tolist(), ids.tolist(), strict=True):
        line = msp.add_line((x0, y0), (x1, y1), dxfattribs={"layer": "walls"})
        line.set_xdata(DXF_APPID, [(_XDATA_ID, int(seg_id))])
    for x, y in checked.centroids.tolist():
        msp.add_point((x, y), dxfattribs={"layer": "centroids"})
    if checked.trajectory.shape[0] >= 2:
        msp.add_lwpolyline(
            checked.trajectory[:, 1:3].tolist(), format="xy", dxfattribs={"layer": "trajectory"}
        )
    return doc


def encode_dxf(snapshot: MapSnapshot) -> bytes:
    """The DXF file of ``snapshot`` (layout in the module docstring) as bytes. Raises
    :class:`~shared.errors.InvalidInputError` for bad snapshot arrays or segment ids beyond 32 bits."""
    doc = _drawing(snapshot)
    stream = io.StringIO()
    doc.write(stream)
    return stream.getvalue().encode(doc.output_encoding)


def write_dxf(path: str | os.PathLike[str], snapshot: MapSnapshot) -> None:
    """Write ``snapshot`` to ``path`` as DXF, atomically. Errors as :func:`encode_dxf`, and
    :class:`~shared.export.errors.ExportIOError` when the file cannot be written."""
    data = encode_dxf(snapshot)
    atomic_write_bytes(path, data)
    _log.debug("wrote DXF map %s: %d walls, %d bytes", path, len(snapshot.segments), len(data))


def _open(source: Path) -> Drawing:
    from ezdxf.filemanagement import readfile
    from ezdxf.lldxf.const import DXFError

    try:
        with source.open("rb"):
            pass
    except OSError as exc:
        raise ExportIOError(f"cannot read {source}: {exc.strerror or exc}") from exc
    try:
        return readfile(source)
    except (OSError, DXFError, ValueError, UnicodeError) as exc:
        raise DXFFormatError(f"{source}: {exc}: expected a DXF drawing") from exc


def _metres_per_unit(doc: Drawing, source: Path) -> float:
    code = doc.header.get("$INSUNITS", 0)
    factor = _METRES_PER_UNIT.get(code) if isinstance(code, int) else None
    if factor is None:
        raise DXFFormatError(
            f"{source}: $INSUNITS = {code!r}: expected a length unit code convertible to metres "
            f"({', '.join(str(k) for k in _METRES_PER_UNIT)}; 6 = metres, 4 = millimetres)"
        )
    return factor


def _segment_id(entity: DXFEntity) -> int:
    if not entity.has_xdata(DXF_APPID):
        return -1
    values = [t.value for t in entity.get_xdata(DXF_APPID) if t.code == _XDATA_ID]
    return int(values[0]) if values else -1


def read_dxf(path: str | os.PathLike[str]) -> DXFMap:
    """Read walls, centroids and trajectory from a DXF file (module docstring), in metres.

    Raises :class:`~shared.export.errors.ExportIOError` when the file cannot be read and
    :class:`~shared.export.errors.DXFFormatError` when it is not a readable DXF or has unknown units.
    O(entities).
    """
    from ezdxf.entities.line import Line
    from ezdxf.entities.lwpolyline import LWPolyline
    from ezdxf.entities.point import Point

    source = Path(path)
    doc = _open(source)
    scale = _metres_per_unit(doc, source)
    segments: list[list[float]] = []
    ids: list[int] = []
    centroids: list[list[float]] = []
    trajectory: list[list[float]] = []
    for entity in doc.modelspace():
        layer = str(entity.dxf.get("layer", "0")).lower()
        if isinstance(entity, Line) and layer == "walls":
            start, end = entity.dxf.start, entity.dxf.end
            segments.append([start.x, start.y, end.x, end.y])
            ids.append(_segment_id(entity))
        elif isinstance(entity, Point) and layer == "centroids":
            loc = entity.dxf.location
            centroids.append([loc.x, loc.y])
        elif isinstance(entity, LWPolyline) and layer == "trajectory" and not trajectory:
            trajectory = [[float(x), float(y)] for x, y in entity.get_points("xy")]
    out = DXFMap(
        np.array(segments, dtype=np.float64).reshape(-1, 4) * scale,
        np.array(ids, dtype=np.intp),
        np.array(centroids, dtype=np.float64).reshape(-1, 2) * scale,
        np.array(trajectory, dtype=np.float64).reshape(-1, 2) * scale,
    )
    _log.debug("read %d walls from %s", out.segments.shape[0], source)
    return out
