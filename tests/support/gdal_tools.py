"""The GDAL command-line tools as a second reader of the map files: ``gdalinfo``, ``gdalwarp``
and ``ogr2ogr`` run as subprocesses (the system's GDAL, e.g. Debian 12's 3.6.2 with PROJ 9.1,
not the GDAL inside rasterio's wheel), and the checks the tests share: that GDAL reads a file,
and that a map warped to WGS84 longitude and latitude has its peak where the project put it."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import rasterio

#: The tools the tests run (all in Debian's gdal-bin).
TOOLS = ("gdalinfo", "gdalwarp", "gdaltransform", "ogrinfo")
#: Skips a test where the system has no GDAL tools (CI installs gdal-bin: .ci/run).
needs_gdal = pytest.mark.skipif(any(shutil.which(tool) is None for tool in TOOLS),
                                reason="GDAL's command-line tools (gdalinfo, gdalwarp, gdaltransform, ogrinfo) are not "
                                       "installed (apt-get install gdal-bin)")
#: Seconds any one GDAL command may take (each takes well under one on these small files).
TIMEOUT = 120


def gdal(*args: str) -> subprocess.CompletedProcess:
    """Run a GDAL tool; fail the test with its stderr unless it succeeds without an ERROR line."""
    done = subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=TIMEOUT)
    assert done.returncode == 0 and "ERROR" not in done.stderr, f"{' '.join(map(str, args))}:\n{done.stderr}"
    return done


def to_lonlat(wkt: str, e, n) -> np.ndarray:
    """``gdaltransform -s_srs WKT -t_srs WGS84``: GDAL's PROJ taking projected points (E, N) to
    (lon, lat), as GDAL reads the CRS a file carries."""
    points = "".join(f"{float(x)!r} {float(y)!r}\n" for x, y in zip(np.ravel(e), np.ravel(n)))
    done = subprocess.run(["gdaltransform", "-s_srs", wkt, "-t_srs", "+proj=longlat +datum=WGS84", "-output_xy"],
                          input=points, capture_output=True, text=True, timeout=TIMEOUT)
    assert done.returncode == 0 and "ERROR" not in done.stderr, done.stderr
    return np.array([[float(v) for v in line.split()] for line in done.stdout.splitlines()])


def gdalinfo(source: str | Path) -> dict:
    """``gdalinfo -json SOURCE`` (a file, or ``NETCDF:"file.nc":variable``) as a dict."""
    return json.loads(gdal("gdalinfo", "-json", source).stdout)


def warp_to_wgs84(source: str | Path, target: Path, grid, frame) -> Path:
    """``gdalwarp -t_srs EPSG:4326`` with nearest-neighbour resampling (each output pixel holds
    one source cell's value, unchanged), GDAL's default error threshold, and output pixels half
    a cell wide and high at the origin (``-tr``: GDAL's own choice may be coarser than a cell
    along one axis, and nearest-neighbour sampling would then skip cells, the peak among them)."""
    lat = math.radians(frame.lat)
    size = (float(0.5 * grid.dx / (METRES_PER_DEGREE * math.cos(lat))), float(0.5 * grid.dy / METRES_PER_DEGREE))
    gdal("gdalwarp", "-q", "-overwrite", "-t_srs", "EPSG:4326", "-r", "near", "-tr", repr(min(size)), repr(min(size)),
         "-of", "GTiff", source, target)
    return target


#: Metres of one degree of latitude, to the nearest kilometre (to size the warped pixels only).
METRES_PER_DEGREE = 111_000.0


def check_warped_peaks(warped: Path, maps: list[np.ndarray], grid, frame) -> None:
    """Each band of the warped file holds the peak of its map (``maps``: one (ny, nx) array per
    band, rows south to north, on ``grid`` in ``frame``), and every warped pixel holding that
    peak lies within one cell of the peak cell: GDAL puts the peak where the project says, to a
    cell (its pixels half a cell wide, nearest-neighbour resampling, and GDAL's default
    0.125-pixel approximation of the transformation move it by less than that)."""
    with rasterio.open(warped) as dst:
        assert dst.crs.to_epsg() == 4326 and dst.count == len(maps)
        for band, values in enumerate(maps, start=1):
            values = np.asarray(values)
            warped_values = dst.read(band, masked=True)  # without the pixels outside the grid (nodata)
            peak = values.max()
            top = float(warped_values.max())
            assert top == pytest.approx(float(peak), rel=2**-23)  # float32 bands keep 24 bits
            rows, cols = np.nonzero(warped_values.filled(-np.inf) == top)
            lon, lat = rasterio.transform.xy(dst.transform, rows, cols)  # pixel centres
            x, y = frame.local(np.asarray(lat), np.asarray(lon))
            # the peak cells: a symmetric map may have several, equal to float32 rounding
            pi, pj = np.nonzero(values >= peak * (1.0 - 2**-23))
            off = np.maximum(np.abs(np.asarray(x)[:, None] - grid.x[pj][None, :]) / grid.dx,
                             np.abs(np.asarray(y)[:, None] - grid.y[pi][None, :]) / grid.dy)
            assert np.all(off.min(axis=1) <= 1.0), (band, off.min(axis=1).max())


def layer_sources(info: dict) -> list[str]:
    """The ``NETCDF:"file":variable`` subdatasets of a NetCDF's gdalinfo that are maps (y, x) of
    a layer or of its cell probabilities (not bounds, latitude or longitude)."""
    found = []
    for key, name in info.get("metadata", {}).get("SUBDATASETS", {}).items():
        if key.endswith("_NAME") and not name.rsplit(":", 1)[1] in ("x_bounds", "y_bounds", "lat", "lon"):
            found.append(name)
    return found
