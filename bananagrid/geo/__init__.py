"""Maps on the Earth: the geographic frame of a scene and the field's file formats.

* :mod:`~bananagrid.geo.frame` — :class:`GeoFrame`: local metres (x east, y north) about a
  last fix given in latitude and longitude, in a projection chosen for accuracy;
* :mod:`~bananagrid.geo.dataset` — CF-1.10 xarray Datasets and NetCDF files of results;
* :mod:`~bananagrid.geo.geotiff` — a scene's maps as one multi-band GeoTIFF;
* :mod:`~bananagrid.geo.areas` — search areas: probability-mass regions as polygons, with the
  probability they enclose recomputed from the cells and its bound;
* :mod:`~bananagrid.geo.geojson` — search areas as RFC 7946 GeoJSON in WGS84;
* :mod:`~bananagrid.geo.kml` — the same search areas, and the fix and stations, as KML for
  Google Earth and chart plotters;
* :mod:`~bananagrid.geo.panels`, :mod:`~bananagrid.geo.files` — the maps a file holds, checked
  once, and files written whole or not at all;
* :mod:`~bananagrid.geo.inputs` — tracks, last fixes and bearings read from CSV, GPX, NMEA 0183
  (GGA, RMC, AIS position reports) and GeoJSON;
* :mod:`~bananagrid.geo.libraries` — the optional libraries of the ``geo`` extra.

pyproj, xarray, netCDF4, rasterio and shapely are the ``geo`` extra
(``pip install 'bananagrid[geo]'``); they are loaded when first used.
"""
