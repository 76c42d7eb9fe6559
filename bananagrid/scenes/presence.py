r"""The ``[array]`` domain of a scene: a ceiling array, a room and a presence law (Pessentheiner).

A scene document whose top level has an ``[array]`` table (instead of ``[grid]``) computes a
presence law on the angular cells of an array;
:func:`bananagrid.scenes.load.parse_scene` hands its tables to :func:`array_scene_fields` and
builds the one :class:`~bananagrid.scenes.load.Scene` from them: the lattice is its domain and
the ``[presence]`` table its one layer, whose kind (``"mixture"``, ``"uniform"``) is a kind of the
registry computed on the ``"array"`` domain. The schema (see ``docs/scenes.md``, "Presence
scenes"):

- ``[scene]``: ``name`` (required), ``title``, ``description``;
- ``[array]``: ``geometry`` ("line", "plane" or "frustum"), ``h`` (m), ``dh`` (m, frustum),
  ``azimuth_step_deg``, ``elevation_step_deg``, ``azimuth_range_deg``, ``elevation_range_deg``
  (whole degrees: the paper's 16-bit integer angles, Section 2);
- ``[room]``: ``x``, ``y``, ``z`` ranges in the array frame (m, z up, the floor at negative z):
  the region S the probabilities are conditioned on;
- ``[presence]``: ``kind`` (a kind of the registry on the ``"array"`` domain) and the rest of
  the table, which the kind's class reads (its ``scene_table``: a mixture's
  ``[presence.components.NAME]`` tables with ``weight``, ``mean`` and ``cov`` or ``sd_x``,
  ``sd_y``, ``rho``, ``sd_z``; a uniform law takes the ``[room]``);
- ``[output]``: ``dtype``, ``far``, ``log10_floor``, ``mass_levels``.

Every key is checked once here; errors name the file, the key path, the value and what is
allowed, as for grid scenes (the helpers of :mod:`bananagrid.scenes.keys` are shared).
"""

from __future__ import annotations

import math

from ..contours import DEFAULT_MASS_LEVELS, mass_levels
from ..domains.angular_lattice import AngularLattice
from ..domains.region import Region
from ..models.presence import AXES as LAW_AXES
from ..models.presence import MAX_LENGTH
from ..models.registry import MODEL_KINDS, Registry
from ..validate import BananagridError
from . import keys
from .keys import DTYPES, SceneKeyError, check_keys, show

__all__ = [
    "array_scene_fields", "GEOMETRIES", "LAYER_NAME",
    "TOP_KEYS", "ARRAY_KEYS", "ROOM_KEYS", "OUTPUT_KEYS",
]

GEOMETRIES = ("line", "plane", "frustum")
TOP_KEYS = ("scene", "array", "room", "presence", "output")
SCENE_KEYS = ("name", "title", "description")
ARRAY_KEYS = ("geometry", "h", "dh", "azimuth_step_deg", "elevation_step_deg", "azimuth_range_deg",
              "elevation_range_deg")
ROOM_KEYS = ("x", "y", "z")
OUTPUT_KEYS = ("dtype", "far", "log10_floor", "mass_levels")
#: The name of an array scene's one layer (its entity in the recording).
LAYER_NAME = "presence"
#: Axes of the presence law per geometry.
AXES = {"line": LAW_AXES[:1], "plane": LAW_AXES[:2], "frustum": LAW_AXES}
#: Default direction ranges, degrees: line azimuths inclusive, plane/frustum azimuths a full
#: turn (end excluded), elevations inclusive from the horizon to the nadir.
DEFAULT_AZIMUTH_RANGE = {"line": (180, 360), "plane": (0, 360), "frustum": (0, 360)}
DEFAULT_ELEVATION_RANGE = (90, 180)


# --- parsing ----------------------------------------------------------------------------------


def array_scene_fields(doc: dict, kinds: Registry = MODEL_KINDS) -> dict:
    """Validate a parsed ``[array]`` scene document table by table (raises ``SceneKeyError``,
    which :func:`bananagrid.scenes.load.parse_scene` prefixes with the source) and return the
    :class:`~bananagrid.scenes.load.Scene` fields it gives: ``name``, ``title``,
    ``description``, ``domain`` (the lattice), ``layer`` (``(kind, params)`` of the presence
    law, a kind of ``kinds`` on the ``"array"`` domain), ``region``, ``room_z``,
    ``component_names``, ``dtype``, ``far``, ``log10_floor`` and ``mass_levels``."""
    check_keys(doc, TOP_KEYS, "", note=" (a presence scene, since it has [array])")
    head = keys.table(doc, "scene", required=True)
    check_keys(head, SCENE_KEYS, "scene")
    name = keys.name(head.get("name"), "scene.name", required=True)
    title = keys.text(head, "title", "scene", default=name)
    description = keys.text(head, "description", "scene", default="")
    lattice = _array(keys.table(doc, "array", required=True))
    room, room_z = _room(keys.table(doc, "room"), lattice) if "room" in doc else (None, None)
    kind, params, names, presence = _presence(keys.table(doc, "presence", required=True), lattice, room,
                                              kinds.on("array"))
    dtype, far, floor, levels = _output(keys.table(doc, "output"))
    if room is not None:  # every law's cells are conditioned on the room: it must hold some mass
        try:
            p_s = presence.region_probability(room)
        except BananagridError as exc:
            raise SceneKeyError(f"room: {exc}") from None
        if not p_s > 0.0:
            raise SceneKeyError(f"room = {show(doc['room'])}: the {kind} law gives the room no mass (p(S) = {p_s!r})")
    return dict(
        name=name, title=title, description=description, domain=lattice, layer=(kind, params), region=room,
        room_z=room_z, component_names=names, dtype=dtype, far=far, log10_floor=floor, mass_levels=levels,
    )


def _array(table: dict) -> AngularLattice:
    """``[array]``: the lattice, angles in whole degrees."""
    check_keys(table, ARRAY_KEYS, "array")
    geometry = table.get("geometry")
    if geometry not in GEOMETRIES:
        shown = "missing" if geometry is None else f"= {show(geometry)}"
        raise SceneKeyError(f"array.geometry {shown}: must be one of {', '.join(map(show, GEOMETRIES))}")
    if "h" not in table:
        raise SceneKeyError("array.h: missing; the depth of the target below the array, m (> 0)")
    h = keys.number(table["h"], "array.h")
    if not (math.isfinite(h) and h > 0.0):
        raise SceneKeyError(f"array.h = {show(table['h'])}: must be finite and > 0 (m below the array)")
    dh = 0.0
    if geometry == "frustum":
        if "dh" not in table:
            raise SceneKeyError("array.dh: missing; the frustum's slab half-thickness, m (0 < dh < h)")
        dh = keys.number(table["dh"], "array.dh")
        if not (math.isfinite(dh) and 0.0 < dh < h):
            raise SceneKeyError(f"array.dh = {show(table['dh'])}: must be in (0, h = {show(table['h'])}) m")
    elif "dh" in table:
        raise SceneKeyError(f"array.dh = {show(table['dh'])}: only the frustum geometry has a slab (geometry = {show(geometry)})")
    if geometry == "line":
        for key in ("elevation_step_deg", "elevation_range_deg"):
            if key in table:
                raise SceneKeyError(f"array.{key} = {show(table[key])}: the line geometry has azimuths only")
    da = _whole_degrees(table.get("azimuth_step_deg", 1), "array.azimuth_step_deg", 1, 180)
    a0, a1 = _degree_range(table, "azimuth_range_deg", DEFAULT_AZIMUTH_RANGE[geometry],
                           (180, 360) if geometry == "line" else (-360, 720))
    if geometry == "line":
        if a1 - a0 == 0 and a0 in (180, 360):
            raise SceneKeyError(f"array.azimuth_range_deg = {show(table['azimuth_range_deg'])}: the only direction is horizontal")
    elif not 0 < a1 - a0 <= 360:
        raise SceneKeyError(
            f"array.azimuth_range_deg = {show(table['azimuth_range_deg'])}: the span must be in (0, 360] "
            "(directions first, first + step, ..., last excluded)"
        )
    if (a1 - a0) % da:
        raise SceneKeyError(
            f"array.azimuth_step_deg = {show(table.get('azimuth_step_deg', 1))}: does not divide the azimuth "
            f"span {a1 - a0} deg of array.azimuth_range_deg = [{a0}, {a1}]"
        )
    kwargs = dict(geometry=geometry, h=h, dh=dh, azimuth_step=math.radians(da),
                  azimuth_range=(math.radians(a0), math.radians(a1)))
    if geometry != "line":
        de = _whole_degrees(table.get("elevation_step_deg", 1), "array.elevation_step_deg", 1, 90)
        t0, t1 = _degree_range(table, "elevation_range_deg", DEFAULT_ELEVATION_RANGE, (90, 180))
        if t1 == 90:
            raise SceneKeyError(f"array.elevation_range_deg = {show(table['elevation_range_deg'])}: the horizon alone never meets the target")
        if (t1 - t0) % de:
            raise SceneKeyError(
                f"array.elevation_step_deg = {show(table.get('elevation_step_deg', 1))}: does not divide the "
                f"elevation span {t1 - t0} deg of array.elevation_range_deg = [{t0}, {t1}]"
            )
        kwargs.update(elevation_step=math.radians(de), elevation_range=(math.radians(t0), math.radians(t1)))
    try:
        return AngularLattice(**kwargs)
    except BananagridError as exc:  # the checks above should leave nothing; say where if not
        raise SceneKeyError(f"array: {exc}") from None


def _whole_degrees(value, path: str, low: int, high: int) -> int:
    number = keys.number(value, path)
    if not (math.isfinite(number) and number == int(number) and low <= number <= high):
        raise SceneKeyError(
            f"{path} = {show(value)}: must be a whole number of degrees in [{low}, {high}] "
            "(the paper's integer angles, Section 2)"
        )
    return int(number)


def _degree_range(table: dict, key: str, default, allowed) -> tuple[int, int]:
    path = f"array.{key}"
    if key not in table:
        return default
    value = table[key]
    if not isinstance(value, list) or len(value) != 2:
        raise SceneKeyError(f"{path} = {show(value)}: expected a pair [first, last] of whole degrees")
    lo, hi = allowed
    first, last = (_whole_degrees(v, f"{path}[{k}]", lo, hi) for k, v in enumerate(value))
    if last < first:
        raise SceneKeyError(f"{path} = {show(value)}: first must be <= last")
    return first, last


def _room(table: dict, lattice: AngularLattice) -> tuple[Region, tuple | None]:
    """``[room]``: the box S in the array frame; the law's axes are required."""
    check_keys(table, ROOM_KEYS, "room")
    geometry = lattice.geometry
    ranges = {}
    for axis in ROOM_KEYS:
        if axis not in table:
            if axis in AXES[geometry]:
                raise SceneKeyError(f"room.{axis}: missing; the {geometry} geometry needs {', '.join(AXES[geometry])} ranges [low, high] in m")
            continue
        if geometry == "line" and axis == "y":
            raise SceneKeyError(f"room.y = {show(table['y'])}: the line geometry (Section 4) has one horizontal axis, x; "
                            "give x (and z for the drawing)")
        ranges[axis] = _range(table[axis], f"room.{axis}")
    z = ranges.get("z")
    if z is not None:
        if geometry == "frustum":
            d0, d1 = lattice.depths
            if not (z[0] < -d0 and z[1] > -d1):
                raise SceneKeyError(
                    f"room.z = {show(table['z'])}: misses the slab z in [{-d1:g}, {-d0:g}] "
                    f"(depths h - dh to h + dh below the array)"
                )
        elif not z[0] <= -lattice.h <= z[1]:
            raise SceneKeyError(
                f"room.z = {show(table['z'])}: the target plane z = -h = {-lattice.h:g} m lies outside the room"
            )
    region = Region(*(ranges[a] for a in AXES[geometry]))
    return region, z


def _range(value, path: str) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise SceneKeyError(f"{path} = {show(value)}: expected a pair of numbers [low, high] in m")
    lo, hi = (_length(v, f"{path}[{k}]") for k, v in enumerate(value))
    if not hi > lo:
        raise SceneKeyError(f"{path} = {show(value)}: the upper bound must exceed the lower")
    return lo, hi


def _presence(table: dict, lattice: AngularLattice, room: Region | None, kinds: Registry):
    """``[presence]``: (kind, model parameters, part names, the law). The kind's class reads its
    table (``scene_table``: a mixture's components, a uniform law's room)."""
    kind = table.get("kind")
    if not isinstance(kind, str) or kind not in kinds:  # a list or a table is no kind (nor hashable)
        shown = "missing" if kind is None else f"= {show(kind)}"
        raise SceneKeyError(f"presence.kind {shown}: must be one of {', '.join(map(show, kinds))}")
    read = getattr(kinds[kind].cls, "scene_table", None)
    if read is None:  # a law of another package without the hook
        raise SceneKeyError(f"presence.kind = {show(kind)}: {kinds[kind].cls.__name__} has no scene_table(table, *, "
                            "path, lattice, room) to read its [presence] table")
    try:
        params, names = read(table, path="presence", lattice=lattice, room=room)
    except BananagridError as exc:  # its messages name the key path
        raise SceneKeyError(str(exc)) from None
    try:
        law = kinds[kind].build(params)
    except BananagridError as exc:  # the table's checks should leave nothing; say where if not
        raise SceneKeyError(f"presence: {exc}") from None
    return kind, params, names, law


def _length(value, path: str) -> float:
    """A position in metres: finite, |value| <= MAX_LENGTH."""
    number = _finite(value, path)
    if not abs(number) <= MAX_LENGTH:
        raise SceneKeyError(f"{path} = {show(value)}: must be within +-{MAX_LENGTH:g} m")
    return number


def _finite(value, path: str) -> float:
    number = keys.number(value, path)
    if not math.isfinite(number):
        raise SceneKeyError(f"{path} = {show(value)}: must be finite")
    return number


def _output(table: dict) -> tuple[str, float | None, float, tuple]:
    """``[output]``: kernel dtype, drawing radius without a room, colour-scale floor and
    probability-mass levels."""
    check_keys(table, OUTPUT_KEYS, "output")
    dtype = table.get("dtype", "float64")
    if dtype not in DTYPES:
        raise SceneKeyError(f"output.dtype = {show(dtype)}: must be one of {', '.join(map(show, DTYPES))}")
    far = None
    if "far" in table:
        far = _finite(table["far"], "output.far")
        if not far > 0.0:
            raise SceneKeyError(f"output.far = {show(table['far'])}: must be > 0 (m)")
    floor = _finite(table.get("log10_floor", -12.0), "output.log10_floor")
    if not -300.0 <= floor < 0.0:
        raise SceneKeyError(f"output.log10_floor = {show(table['log10_floor'])}: must be in [-300, 0) (log10 of a probability)")
    levels = DEFAULT_MASS_LEVELS
    if "mass_levels" in table:
        if not isinstance(table["mass_levels"], list):
            raise SceneKeyError(f"output.mass_levels = {show(table['mass_levels'])}: expected a list of probabilities in (0, 1)")
        try:
            levels = mass_levels(table["mass_levels"], key="output.mass_levels")
        except BananagridError as exc:
            raise SceneKeyError(str(exc)) from None
    return dtype, far, floor, levels
