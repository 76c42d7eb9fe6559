"""Inspect a recording without a viewer: what it holds and where the target is.

:func:`inspect_recording` summarises the timelines and entities of an ``.rrd`` file;
:func:`layer_summaries` and :func:`cell_map_summaries` say, per density layer or angular cell
map and time, where the target is (the peak and its place, the captured mass, the
probability-mass regions); :func:`format_inspection` renders all of it for people and
:func:`json_ready` for scripts. Reading the file is :mod:`bananagrid.recording.readback`'s.

Places are world metres, x east and y north (a cell map's: the array frame, z up). A
geographic position (latitude, longitude) would go beside them: in the summaries as
``peak_lat``, ``peak_lon`` and in the report in :func:`_place`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable

import numpy as np

from ..contours import DEFAULT_MASS_LEVELS, cell_regions, mass_regions
from ..domains.angular_lattice import AngularLattice
# The readers moved to readback; they stay importable from here for existing callers.
from .evidence import EVIDENCE_ENTITY
from .plan import PERIODS_ENTITY, PLAN_ENTITY
from .readback import (
    IMAGE_BUFFER, IMAGE_FORMAT, RecordedCellMap, decode_image, open_recording, plain_cell,
    read_cell_maps, read_depth_image, read_layers, recording_rows, seconds,
)

__all__ = [
    "IMAGE_BUFFER", "IMAGE_FORMAT", "cell_map_summaries", "decode_image", "format_inspection", "inspect_recording",
    "json_ready", "layer_summaries", "open_recording", "plan_summary", "evidence_summary", "plain_cell", "read_depth_image", "recording_rows",
]

_SCALARS = "Scalars:scalars"
#: Significant digits of a recorded float in the text report (JSON keeps every digit).
FLOAT_DIGITS = 8


# --- what the recording holds -----------------------------------------------------------------


def inspect_recording(path: str | os.PathLike) -> dict:
    """Summarise an ``.rrd`` file without a viewer.

    Returns
    -------
    dict
        ``path``, ``application_id``, ``recording_id``, ``blueprint`` (whether a blueprint
        store is embedded), ``timelines`` ``{name: {kind, count, min, max, values}}`` (seconds
        for durations) and ``entities`` ``{path: summary}``. An entity summary has
        ``archetypes`` and ``components`` (sorted names), ``static_rows``, ``temporal_rows``,
        and where present ``image_shapes`` (``(height, width)``), ``value_range``
        (min, max of the finite values over all its images), ``non_finite``
        (``{"nan": count, "inf": count}``, only when some pixel is not finite), ``scalars``
        and ``values`` (AnyValues): lists of ``{"times": {timeline: value}, "values": ...}``
        in time order. Recordings store every
        number as a float (so that a key keeps one type across times); whole ones come back
        as ``int`` (``grid.nx = 1500``).

    Raises
    ------
    BananagridError
        If ``path`` is missing or not a readable recording.
    """
    reader, store = open_recording(path)
    timelines: dict[str, dict] = {}
    entities: dict[str, dict] = {}
    for entity, times, cells in recording_rows(reader, store):
        _add_times(timelines, times)
        _add_row(entities.setdefault(entity, _new_entity()), times, cells)
    info = {
        "path": str(path),
        "application_id": store.application_id,
        "recording_id": store.recording_id,
        "blueprint": bool(reader.blueprints()),
        "timelines": {name: _timeline_summary(t) for name, t in sorted(timelines.items())},
        "entities": {name: _entity_summary(e) for name, e in sorted(entities.items())},
    }
    plan = plan_summary(info["entities"])
    if plan is not None:
        info["plan"] = plan
    found = evidence_summary(info["entities"])
    if found:
        info["evidence"] = found
    return info


def evidence_summary(entities: dict) -> list[dict]:
    """Each recorded posterior (:mod:`bananagrid.recording.evidence`) from
    :func:`inspect_recording`'s ``entities``, by layer then time: ``layer``, ``t`` (s), ``pos``,
    ``normaliser``, ``prior_mass``, ``evidence`` (the names it took) and ``search_pos``
    (``{name: POS}`` of the searches that had begun); empty without evidence."""
    out = []
    for name, entity in entities.items():
        if not (name.startswith(f"/{EVIDENCE_ENTITY}/") and name.endswith("/values")):
            continue
        for row in entity.get("values", []):
            values = row["values"]
            searches, pos = _listed(values.get("searches")), _listed(values.get("search_pos"))
            out.append({
                "layer": values["layer"], "t": values["t"], "pos": values["pos"], "normaliser": values["normaliser"],
                "prior_mass": values.get("prior_mass"), "evidence": _listed(values.get("evidence")),
                "search_pos": {s: p for s, p in zip(searches, pos) if p is not None and math.isfinite(p)},
            })
    return sorted(out, key=lambda item: (item["layer"], item["t"]))


def plan_summary(entities: dict) -> dict | None:
    """A recorded search plan (:mod:`bananagrid.recording.plan`) from :func:`inspect_recording`'s
    ``entities``: its numbers (``layer``, ``t``, ``law``, ``effort_m2``, ``pos``,
    ``marginal_gain``, ``map_mass``, ...) and per kind of areas (``rectangles``, ``bands``) the
    plan's ``pos``, ``effort_m2`` and ``areas`` (``probability``, ``pod``, ``pos``,
    ``track_spacing_m`` each); None when the recording has no plan. A plan over several periods
    gives its totals (:func:`~bananagrid.recording.plan.periods_values`: ``periods``, ``pos``,
    ``first_detection``, ...) and ``period_plans``: each period's numbers as above, by time."""
    recorded = entities.get(f"/{PLAN_ENTITY}/values", {}).get("values")
    if not recorded:
        return None
    totals = entities.get(f"/{PLAN_ENTITY}/{PERIODS_ENTITY}/values", {}).get("values")
    if totals:
        out = {key: (_listed(value) if key in PERIODS_LISTS else value)
               for key, value in totals[-1]["values"].items()}
        out["period_plans"] = sorted((_one_plan(dict(item["values"])) for item in recorded), key=lambda v: v["t"])
        return out
    return _one_plan(dict(recorded[-1]["values"]))


#: A plan over several periods' numbers that are lists (one item comes back as a scalar).
PERIODS_LISTS = ("times_s", "efforts_m2", "first_detection", "period_pos", "pos_by_sweep")


def _one_plan(values: dict) -> dict:
    """One recorded plan's (or period's) numbers, its areas gathered per kind."""
    out = {key: value for key, value in values.items() if not key.startswith(("rectangles_", "bands_"))}
    for name in ("rectangles", "bands"):
        if f"{name}_pos" not in values:
            continue
        columns = [_listed(values.get(f"{name}_{key}")) for key in ("probability", "pod", "track_spacing_m")]
        out[name] = {
            "pos": values[f"{name}_pos"], "effort_m2": values[f"{name}_effort_m2"],
            "areas": [{"probability": p, "pod": pod, "pos": p * pod, "track_spacing_m": spacing}
                      for p, pod, spacing in zip(*columns)],
        }
    return out


def _listed(value) -> list:
    """A recorded list (one item comes back as a scalar)."""
    return value if isinstance(value, list) else [] if value is None else [value]


def _add_times(timelines: dict, times: dict) -> None:
    """Collect the values seen on each timeline."""
    for name, (kind, value) in times.items():
        timelines.setdefault(name, {"kind": kind, "values": set()})["values"].add(value)


def _timeline_summary(timeline: dict) -> dict:
    """Kind, count, range and sorted distinct values of one timeline (seconds where timed)."""
    kind = timeline["kind"]
    values = [seconds(kind, v) for v in sorted(timeline["values"])]
    return {
        "kind": kind, "count": len(values), "min": values[0], "max": values[-1], "values": values
    }


def _new_entity() -> dict:
    """An empty per-entity accumulator."""
    return {"archetypes": set(), "components": set(), "static_rows": 0, "temporal_rows": 0,
            "image_shapes": set(), "ranges": [], "nan": 0, "inf": 0, "scalars": [], "values": []}


def _add_row(acc: dict, times: dict, cells: dict) -> None:
    """Fold one row into its entity's accumulator."""
    acc["static_rows" if not times else "temporal_rows"] += 1
    acc["components"].update(cells)
    acc["archetypes"].update(archetype for archetype, _ in cells.values())
    when = {name: seconds(kind, value) for name, (kind, value) in times.items()}
    if IMAGE_BUFFER in cells and IMAGE_FORMAT in cells:
        image = decode_image(cells[IMAGE_BUFFER][1], cells[IMAGE_FORMAT][1])
        acc["image_shapes"].add(image.shape)
        finite = image[np.isfinite(image)] if np.issubdtype(image.dtype, np.floating) else image
        if finite.size:
            acc["ranges"].append((float(np.min(finite)), float(np.max(finite))))
        if finite.size < image.size:  # NaN and infinities are counted, never folded into the range
            acc["nan"] += int(np.count_nonzero(np.isnan(image)))
            acc["inf"] += int(np.count_nonzero(np.isinf(image)))
    if _SCALARS in cells:
        acc["scalars"].append({"times": when, "values": _whole(plain_cell(cells[_SCALARS][1]))})
    untyped = {
        name: _whole(plain_cell(cell)) for name, (archetype, cell) in cells.items() if archetype == "AnyValues"
    }
    if untyped:
        acc["values"].append({"times": when, "values": dict(sorted(untyped.items()))})


def _whole(value):
    """A recorded value with whole floats as ints (lists item by item)."""
    if isinstance(value, list):
        return [_whole(v) for v in value]
    if isinstance(value, float) and value.is_integer() and abs(value) < 2**53:
        return int(value)
    return value


def _entity_summary(acc: dict) -> dict:
    """Plain-data summary of one entity; empty parts are left out."""
    summary = {
        "archetypes": sorted(acc["archetypes"]),
        "components": sorted(acc["components"]),
        "static_rows": acc["static_rows"],
        "temporal_rows": acc["temporal_rows"],
    }
    if acc["image_shapes"]:
        summary["image_shapes"] = sorted(acc["image_shapes"])
        if acc["ranges"]:
            lows, highs = zip(*acc["ranges"])
            summary["value_range"] = (min(lows), max(highs))
        if acc["nan"] or acc["inf"]:
            summary["non_finite"] = {"nan": acc["nan"], "inf": acc["inf"]}
    for key in ("scalars", "values"):
        if acc[key]:
            summary[key] = sorted(acc[key], key=lambda sample: sorted(sample["times"].items()))
    return summary


# --- where the target is ----------------------------------------------------------------------


def layer_summaries(path: str | os.PathLike, levels: Iterable[float] = DEFAULT_MASS_LEVELS) -> list[dict]:
    """Where the target is, per density layer and time of a recording.

    Everything is computed from the recorded float32 density (read back by
    :func:`bananagrid.recording.readback.read_rasters`), except the captured mass, which the run
    recorded in float64.

    Parameters
    ----------
    path : path-like
        The ``.rrd`` file.
    levels : iterable of float
        Probability-mass levels, each in (0, 1).

    Returns
    -------
    list of dict
        By time, then layer: ``layer``, ``entity``, ``t`` (s), ``mass`` (the raw captured mass,
        before normalising), ``normalised``, ``peak`` (the highest density, m^-2), ``peak_x``,
        ``peak_y`` (its cell centre, m, x east, y north; None where the image is all zero), ``grid`` (``origin``, ``dx``, ``dy``,
        ``nx``, ``ny``) and ``regions``: per level, as
        :meth:`bananagrid.contours.MassRegion.describe` (``probability``, ``reached``,
        ``density``, ``enclosed``, ``cells``, ``area`` in m^2) plus ``area_km2``. Empty for a
        recording without density layers (an array scene's).

    Raises
    ------
    BananagridError
        If the file is not a readable recording, or ``levels`` are not probabilities.
    """
    out = []
    for item in read_layers(path):
        raster = item.raster
        i, j = np.unravel_index(int(np.argmax(raster.values)), raster.values.shape)
        regions = []
        for region in mass_regions(raster, levels):
            described = region.describe()
            described["area_km2"] = None if described["area"] is None else described["area"] / 1e6
            regions.append(described)
        peak = float(raster.values[i, j])
        found = peak > 0.0
        x, y = float(raster.x[j]), float(raster.y[i])
        lat, lon = raster.frame.geographic(x, y) if raster.frame is not None and found else (None, None)
        out.append({
            "layer": item.layer, "entity": item.entity, "t": item.t, "mass": raster.mass,
            "normalised": raster.normalised, "peak": peak,
            "peak_x": x if found else None, "peak_y": y if found else None,
            "peak_lat": None if lat is None else float(lat), "peak_lon": None if lon is None else float(lon),
            "utc": None if raster.frame is None or raster.frame.time is None else _iso(raster.frame.utc(item.t)),
            "crs": None if raster.frame is None else raster.frame.crs_name,
            "grid": raster.grid.describe(), "regions": regions,
        })
    return out


def _iso(when) -> str:
    """A UTC time as ISO 8601 with ``Z``, to the millisecond when it has fractions; a year
    below 1000 with four digits (``strftime`` drops them on some platforms)."""
    text = when.replace(tzinfo=None).isoformat(timespec="milliseconds").removesuffix(".000")
    return text + "Z"


def cell_map_summaries(path: str | os.PathLike, levels: Iterable[float] = DEFAULT_MASS_LEVELS) -> list[dict]:
    """Where the target is, per angular cell map (an array scene's) and time of a recording.

    The numbers are cell probabilities p(C | S), not densities, from the recorded float32
    table (:func:`bananagrid.recording.readback.read_cell_maps`).

    Parameters
    ----------
    path : path-like
        The ``.rrd`` file.
    levels : iterable of float
        Probability-mass levels, each in (0, 1).

    Returns
    -------
    list of dict
        By time, then entity: ``entity``, ``t`` (s), ``geometry`` (``line``, ``plane``,
        ``frustum``; None if the lattice is not recorded), ``cells`` (int), ``region_probability``
        (p(S)), ``total`` (sum of p(C | S)), ``peak`` (the highest cell probability),
        ``peak_azimuth_deg``, ``peak_elevation_deg`` (its direction; elevation from +z, 180 the
        nadir; None for a line), ``peak_x``, ``peak_y``, ``peak_z`` (the centroid of its cell
        on the target, m, array frame, z up; None for an unbounded horizon cell) and
        ``regions``: per level ``probability``, ``reached``, ``cell_probability`` (the
        boundary cell's), ``enclosed`` and ``cells``. Empty for a recording without cell maps.

    Raises
    ------
    BananagridError
        If the file is not a readable recording, or ``levels`` are not probabilities.
    """
    out = []
    for item in read_cell_maps(path):
        summary = item.summary
        flat = int(np.argmax(item.prob))
        index = np.unravel_index(flat, item.prob.shape)
        entry = {
            "entity": item.entity, "t": item.t,
            "geometry": None if item.lattice is None else item.lattice.geometry,
            "cells": int(item.prob.size), "region_probability": _float(summary.get("region_probability")),
            "total": _float(summary.get("total")), "peak": float(item.prob[index]),
        }
        entry.update(_peak_cell(item, index))
        entry["regions"] = [
            {"probability": r.probability, "reached": r.reached,
             "cell_probability": None if math.isnan(r.density) else r.density,
             "enclosed": r.enclosed, "cells": r.cells}
            for r in cell_regions(item.prob, levels)
        ]
        out.append(entry)
    return out


def _float(value) -> float | None:
    """A recorded number as float (None if absent or not a number)."""
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def _peak_cell(item: RecordedCellMap, index: tuple) -> dict:
    """Direction (deg) and cell centroid (m) of the cell at ``index``; None where unknown."""
    out = dict.fromkeys(("peak_azimuth_deg", "peak_elevation_deg", "peak_x", "peak_y", "peak_z"))
    lattice: AngularLattice | None = item.lattice
    if lattice is None:
        return out
    a = index[0]
    out["peak_azimuth_deg"] = math.degrees(float(lattice.azimuths[a]))
    if lattice.geometry == "line":  # the line y = 0, z = -h of the array frame
        x = float(lattice.centroids[a, 0])
        centroid = (x, 0.0, -lattice.h) if math.isfinite(x) else (None,) * 3
    else:
        out["peak_elevation_deg"] = math.degrees(float(lattice.elevations[index[1]]))
        point = lattice.centroids[a, index[1]]
        centroid = tuple(float(v) for v in point) if np.all(np.isfinite(point)) else (None,) * 3
    out["peak_x"], out["peak_y"], out["peak_z"] = centroid
    return out


# --- for scripts ------------------------------------------------------------------------------


def json_ready(value):
    """``value`` as standard JSON data: tuples and sets as lists, NumPy scalars as Python
    numbers, NaN and infinities as None (JSON ``null``)."""
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set)):
        return [json_ready(v) for v in value]
    if isinstance(value, np.generic):
        return json_ready(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


# --- for people -------------------------------------------------------------------------------


def format_inspection(info: dict) -> str:
    """Render :func:`inspect_recording`'s result as a plain-text report.

    Where ``info`` also has ``layers`` (:func:`layer_summaries`) or ``cell_maps``
    (:func:`cell_map_summaries`), where the target is comes first, after the file's header.
    """
    lines = [
        f"recording  {info['path']}",
        f"  application {info['application_id']}, id {info['recording_id']}, "
        f"blueprint {'embedded' if info['blueprint'] else 'none'}",
    ]
    if info.get("layers"):
        lines += ["", "where the target is (density layers; from the recorded float32 images)"]
        for item in info["layers"]:
            lines += _layer_lines(item)
    if info.get("cell_maps"):
        lines += ["", "where the target is (angular cell maps; cell probabilities p(C | S), not densities)"]
        for item in info["cell_maps"]:
            lines += _cell_map_lines(item)
    if info.get("evidence"):
        lines += ["", "after the evidence (the recorded posteriors)"]
        for item in info["evidence"]:
            own = ", ".join(f"{name} {pos:.6f}" for name, pos in item["search_pos"].items())
            # POS is conditioned on the map's reports and land (the evidence that is no search)
            given = ", ".join(name for name in item["evidence"] if name not in item["search_pos"])
            lines += [f"  {item['layer']} at t = {item['t']:g} s after {', '.join(item['evidence']) or 'no evidence yet'}",
                      f"    POS                    {item['pos']:.6f}" + (f" given {given}" if given else "")
                      + (f" (each search alone: {own})" if own else ""),
                      f"    probability of the evidence {item['normaliser']:.6g}"]
    if info.get("plan") and "period_plans" in info["plan"]:
        plan = info["plan"]
        lines += ["", f"where to look next (the recorded plan over {plan['periods']} periods)",
                  f"  layer {plan['layer']}, law {plan['law']}: total POS {plan['pos']:.6f} after {plan['sweeps']} "
                  f"sweeps ({'converged' if plan['converged'] else 'not converged'} to {plan['tol']:g})"]
        for k, period in enumerate(plan["period_plans"]):
            lines += [f"  period {k + 1}: first detection {period.get('first_detection', math.nan):.6f}"]
            lines += _plan_lines(period)
    elif info.get("plan"):
        lines += ["", "where to look next (the recorded plan)"] + _plan_lines(info["plan"])
    lines += ["", "timelines"]
    lines += [_timeline_line(name, t) for name, t in info["timelines"].items()] or ["  (none: static only)"]
    lines += ["", "entities"]
    width = max((len(name) for name in info["entities"]), default=0)
    for name, entity in info["entities"].items():
        lines += _entity_lines(name.ljust(width), entity)
    return "\n".join(lines)


def _layer_lines(item: dict) -> list[str]:
    """One layer at one time: captured mass, peak and place, then the regions as a table."""
    lines = [
        f"  {item['layer']} at t = {item['t']:g} s" + (f" ({item['utc']})" if item.get("utc") else ""),
        f"    captured mass          {_captured(item['mass'], item['normalised'])}",
        f"    peak density           {item['peak']:.6g} m^-2 {_place(item)}",
    ]
    rows = [["region", "area [km²]", "area [m²]", "cells", "holds"]]
    for r in item["regions"]:
        label = f"{100 * r['probability']:g} %"
        if r["reached"]:
            rows.append([label, _square_kilometres(r["area_km2"]), _square_metres(r["area"]), f"{r['cells']:,}",
                         f"{r['enclosed']:.6f}"])
        else:
            rows.append([label, "not reached", "", "", f"{r['enclosed']:.6f}"])  # the grid's whole mass
    return lines + _table(rows, indent=4)


def _cell_map_lines(item: dict) -> list[str]:
    """One cell map at one time: its cells, p(S), the peak cell and where, the regions."""
    geometry = f"{item['geometry']}, " if item["geometry"] else ""
    lines = [
        f"  {item['entity']} at t = {item['t']:g} s ({geometry}{item['cells']:,} cells, "
        f"p(S) = {_show(item['region_probability'])}, sum of p(C | S) = {_show(item['total'])})",
        f"    peak cell probability  {item['peak']:.6g} {_direction(item)}",
    ]
    if item["peak_azimuth_deg"] is not None:
        lines.append(f"    its cell's centroid    {_centroid(item)}")
    rows = [["region", "cells", "holds", "smallest cell probability"]]
    for r in item["regions"]:
        label = f"{100 * r['probability']:g} %"
        if r["reached"]:
            rows.append([label, f"{r['cells']:,}", f"{r['enclosed']:.6f}", f"{r['cell_probability']:.6g}"])
        else:
            rows.append([label, "not reached", f"{r['enclosed']:.6f}", ""])  # every cell's
    return lines + _table(rows, indent=4)


def _plan_lines(plan: dict) -> list[str]:
    """The plan: its map, effort and ideal POS, then each kind of areas as a table."""
    lines = [
        f"  layer {plan['layer']} at t = {plan['t']:g} s, law {plan['law']}, map holds {plan['map_mass']:.6f}",
        f"    effort                 {plan['effort_m2'] / 1e6:.6g} km^2 ({plan['effort_m2']:.6g} m^2)",
        f"    ideal POS              {plan['pos']:.6f}",
        f"    marginal gain          {plan['marginal_gain'] * 1e6:.6g} POS per km^2",
    ]
    for name in ("rectangles", "bands"):
        if name not in plan:
            continue
        flown = plan[name]
        lines.append(f"    {name + ' POS':<22} {flown['pos']:.6f} ({flown['effort_m2'] / 1e6:.6g} km^2 flown)")
        rows = [[name[:-1], "probability", "POD", "POS", "track spacing [m]"]]
        rows += [[f"{'R' if name == 'rectangles' else 'B'}{k + 1}", f"{a['probability']:.6f}", f"{a['pod']:.6f}",
                  f"{a['pos']:.6f}", f"{a['track_spacing_m']:,.1f}"] for k, a in enumerate(flown["areas"])]
        lines += _table(rows, indent=6)
    return lines


def _captured(mass: float | None, normalised: bool) -> str:
    """The captured mass, how far it is from one, and whether the map was then normalised."""
    if mass is None or not math.isfinite(mass):
        return "n/a"
    gap = 1.0 - mass
    after = "the map is normalised to 1" if normalised else "the map is not normalised"
    return f"{mass:.6f} ({abs(gap):.3g} {'missing' if gap >= 0.0 else 'in excess'}; {after})"


def _place(item: dict) -> str:
    """A layer's peak place in words: world metres to the grid's resolution (a geographic
    position would follow here)."""
    if item["peak_x"] is None:
        return "(every cell is zero)"
    step = min(item["grid"]["dx"], item["grid"]["dy"])
    decimals = max(0, -math.floor(math.log10(step / 2.0)))
    place = f"in the cell centred on x = {item['peak_x']:,.{decimals}f} m, y = {item['peak_y']:,.{decimals}f} m (east, north)"
    if item.get("peak_lat") is None:
        return place
    # degrees to a tenth of the cell: 1e-5 deg of latitude is 1.1 m
    places = max(4, -math.floor(math.log10(step / 10.0 / 111_000.0)))
    lat, lon = item["peak_lat"], item["peak_lon"]
    return (f"{place}, {abs(lat):.{places}f} {'N' if lat >= 0 else 'S'} {abs(lon):.{places}f} "
            f"{'E' if lon >= 0 else 'W'}")


def _direction(item: dict) -> str:
    """A cell map's peak cell: its direction, where the lattice is known."""
    if item["peak_azimuth_deg"] is None:
        return "(the lattice is not recorded)"
    out = f"in the cell at azimuth {item['peak_azimuth_deg']:.6g} deg"
    if item["peak_elevation_deg"] is not None:
        out += f", elevation {item['peak_elevation_deg']:.6g} deg (from +z, 180 the nadir)"
    return out


def _centroid(item: dict) -> str:
    """The centroid of a cell map's peak cell on the target, mm resolution."""
    if item["peak_x"] is None:
        return "none (a horizon cell, unbounded)"
    return (f"x = {item['peak_x']:,.3f} m, y = {item['peak_y']:,.3f} m, z = {item['peak_z']:,.3f} m "
            "(array frame, z up)")


def _square_kilometres(value: float | None) -> str:
    """An area in km^2 to 4 significant digits, thousands separated, no exponent."""
    if value is None:
        return "n/a"
    if value == 0.0:
        return "0"
    digits = 3 - int(math.floor(math.log10(abs(value))))
    return f"{round(value, digits):,.{max(digits, 0)}f}"


def _square_metres(value: float | None) -> str:
    """An area in m^2: whole, thousands separated (small ones to 4 significant digits)."""
    if value is None:
        return "n/a"
    return f"{value:,.0f}" if value >= 100 else f"{value:.4g}"


def _table(rows: list[list[str]], indent: int) -> list[str]:
    """Rows of cells as aligned lines: the first column left-aligned, the others right."""
    widths = [max(len(row[k]) for row in rows) for k in range(len(rows[0]))]
    pad = " " * indent
    def line(row: list[str]) -> str:
        cells = [cell.ljust(w) if k == 0 else cell.rjust(w) for k, (cell, w) in enumerate(zip(row, widths))]
        return (pad + "  ".join(cells)).rstrip()

    return [line(row) for row in rows]


def _timeline_line(name: str, timeline: dict) -> str:
    """One line per timeline: kind, number of values and range."""
    unit = " s" if timeline["kind"] in ("duration", "timestamp") else ""
    return (
        f"  {name}  {timeline['kind']}  {timeline['count']} value(s)  "
        f"{timeline['min']:g}{unit} .. {timeline['max']:g}{unit}"
    )


def _entity_lines(name: str, entity: dict) -> list[str]:
    """The entity's headline, then indented details for images, scalars and values."""
    rows = f"{entity['temporal_rows']} temporal + {entity['static_rows']} static row(s)"
    lines = [f"  {name}  {', '.join(entity['archetypes'])}  ({rows})"]
    indent = " " * (len(name) + 4)
    if "image_shapes" in entity:
        shapes = ", ".join(f"{h}x{w}" for h, w in entity["image_shapes"])
        finite = ""
        if "value_range" in entity:
            low, high = entity["value_range"]
            finite = f", values {low:.6g} .. {high:.6g}"
        if "non_finite" in entity:
            bad = entity["non_finite"]
            finite += f"{' (finite ones)' if finite else ', no finite values'}; {bad['nan']:,} NaN, {bad['inf']:,} infinite"
        lines.append(f"{indent}image {shapes} (rows x cols){finite}")
    for sample in entity.get("scalars", []):
        lines.append(f"{indent}{_when(sample['times'])}: {_show(sample['values'])}")
    if "values" in entity:
        latest = entity["values"][-1]
        lines.append(f"{indent}values at {_when(latest['times'])}:")
        lines += [f"{indent}  {key} = {_show(value)}" for key, value in latest["values"].items()]
    return lines


def _show(value) -> str:
    """A recorded value as printed: ints whole, floats to ``FLOAT_DIGITS`` significant digits,
    lists item by item, None as n/a."""
    if value is None:
        return "n/a"
    if isinstance(value, list):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:.{FLOAT_DIGITS}g}"
    return str(value)


def _when(times: dict) -> str:
    """``elapsed=1.5`` style label for a row's times (``static`` for none)."""
    return ", ".join(f"{name}={value:g}" for name, value in sorted(times.items())) or "static"
