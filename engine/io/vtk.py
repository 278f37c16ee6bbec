"""VTK XML files for ParaView: unstructured grids (``.vtu``) and their time series (``.pvd``).

A ``.vtu`` holds points, cells (vertices or line segments) and named arrays on each, written as
base64 binary with 64-bit headers (exact values, no compression); a ``.pvd`` lists the ``.vtu``
of every time and part, which ParaView opens as one animated, multi-block dataset.
"""

from __future__ import annotations

import base64
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

VTK_VERTEX = 1
VTK_LINE = 3
POINTS_PER_CELL = {VTK_VERTEX: 1, VTK_LINE: 2}
_TYPES = {np.dtype(np.float64): "Float64", np.dtype(np.float32): "Float32", np.dtype(np.int64): "Int64",
          np.dtype(np.int32): "Int32", np.dtype(np.int8): "Int8", np.dtype(np.uint8): "UInt8"}


def _array(name: str, values: np.ndarray, indent: str, tuples: bool = False) -> str:
    values = np.ascontiguousarray(values)
    if values.dtype == np.bool_:
        values = values.astype(np.uint8)
    if values.dtype not in _TYPES:
        values = values.astype(np.float64 if np.issubdtype(values.dtype, np.floating) else np.int64)
    components = 1 if values.ndim == 1 else values.shape[1]
    raw = values.astype(values.dtype.newbyteorder("<"), copy=False).tobytes()
    data = base64.b64encode(np.uint64(len(raw)).tobytes() + raw).decode("ascii")
    count = f' NumberOfTuples="{values.shape[0]}"' if tuples else ""
    return (f'{indent}<DataArray type="{_TYPES[values.dtype]}" Name={quoteattr(name)} '
            f'NumberOfComponents="{components}"{count} format="binary">{data}</DataArray>\n')


def write_vtu(path: str | Path, points: np.ndarray, cell_type: int, connectivity: np.ndarray,
              point_data: dict[str, np.ndarray] | None = None, cell_data: dict[str, np.ndarray] | None = None,
              field_data: dict[str, np.ndarray] | None = None) -> None:
    """One unstructured grid: ``points`` (P, 2) placed at z = 0, cells of one ``cell_type`` given by
    ``connectivity`` (C, k) point indices, arrays per point, per cell and for the whole grid
    (``TimeValue`` there is the time ParaView shows)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    connectivity = np.asarray(connectivity, dtype=np.int64).reshape(-1, POINTS_PER_CELL[cell_type])
    cells, per_cell = connectivity.shape
    parts = ['<?xml version="1.0"?>\n',
             '<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">\n',
             "  <UnstructuredGrid>\n"]
    if field_data:
        parts.append("    <FieldData>\n")
        parts += [_array(name, np.atleast_1d(values), "      ", tuples=True) for name, values in field_data.items()]
        parts.append("    </FieldData>\n")
    parts.append(f'    <Piece NumberOfPoints="{len(points)}" NumberOfCells="{cells}">\n')
    for tag, data in (("PointData", point_data), ("CellData", cell_data)):
        parts.append(f"      <{tag}>\n")
        parts += [_array(name, values, "        ") for name, values in (data or {}).items()]
        parts.append(f"      </{tag}>\n")
    parts += ["      <Points>\n", _array("Points", np.column_stack([points, np.zeros(len(points))]), "        "),
              "      </Points>\n", "      <Cells>\n",
              _array("connectivity", connectivity.ravel(), "        "),
              _array("offsets", per_cell * np.arange(1, cells + 1, dtype=np.int64), "        "),
              _array("types", np.full(cells, cell_type, dtype=np.uint8), "        "),
              "      </Cells>\n", "    </Piece>\n", "  </UnstructuredGrid>\n", "</VTKFile>\n"]
    Path(path).write_text("".join(parts))


def write_pvd(path: str | Path, entries: list[tuple[float, int, str]]) -> None:
    """The collection of ``(time, part, file)`` entries, the files relative to ``path``'s folder."""
    rows = "".join(f'    <DataSet timestep="{time:.17g}" part="{part}" file={quoteattr(name)}/>\n'
                   for time, part, name in entries)
    Path(path).write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="1.0" byte_order="LittleEndian">\n'
                          f"  <Collection>\n{rows}  </Collection>\n</VTKFile>\n")
