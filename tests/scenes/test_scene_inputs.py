"""Scenes that take their last fix and bearings from files (``[geo] fix_file``, ``fix_mmsi``,
``bearings_file``), and unknown keys of every table answered with the nearest valid one."""

from __future__ import annotations

import difflib
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.models.registry import MODEL_KINDS
from bananagrid.scenes.load import GEO_KEYS, GRID_KEYS, OUTPUT_KEYS, RADIAL_KEYS, SCENE_KEYS, TOP_KEYS, parse_scene
from bananagrid.scenes import presence

ROOT = Path(__file__).resolve().parents[2]
SHIP = (ROOT / "scenes" / "geo_ship.toml").read_text()
BEARING = (ROOT / "scenes" / "geo_bearing.toml").read_text()

#: geo_ship's fix (60.45 N, 4.60 E at 05:40 UTC, course 200 deg true, 5 m/s) as the last point of
#: a GPX 1.0 track that gives course and speed (the element order of GPX 1.0's wptType).
TRACK_GPX = """<?xml version="1.0" encoding="UTF-8"?>
<gpx version="1.0" creator="tests" xmlns="http://www.topografix.com/GPX/1/0">
<trk><trkseg>
<trkpt lat="60.46" lon="4.61"><time>2026-11-24T05:35:00Z</time><course>199.0</course><speed>5.1</speed></trkpt>
<trkpt lat="60.45" lon="4.60"><time>2026-11-24T05:40:00Z</time><course>200.0</course><speed>5.0</speed></trkpt>
</trkseg></trk>
</gpx>
"""


def from_file(text: str, geo: str) -> str:
    """``text`` with its [geo] table's origin and time replaced by ``geo`` lines."""
    text = re.sub(r"^origin_latlon = .*\n", "", text, flags=re.M)
    text = re.sub(r'^time = "2026.*\n', "", text, flags=re.M)
    return text.replace("[geo]\n", "[geo]\n" + geo + "\n")


def test_fix_file_is_the_origin_time_course_and_speed(tmp_path):
    (tmp_path / "track.gpx").write_text(TRACK_GPX)
    given = parse_scene(SHIP, source="ship.toml")
    text = from_file(SHIP, 'fix_file = "track.gpx"').replace("v0 = 5.0\n", "").replace("heading_deg = 200.0", "")
    (tmp_path / "ship.toml").write_text(text)
    scene = bg.load_scene(tmp_path / "ship.toml")
    assert scene.geo.identity() == given.geo.identity()
    cat, = (layer for layer in scene.layers if layer.name == "cat")
    expected, = (layer for layer in given.layers if layer.name == "cat")
    assert cat.params["v0"] == expected.params["v0"]
    # the course is converted into the grid bearing as heading_deg was: the same arithmetic
    assert cat.params["heading"] == pytest.approx(expected.params["heading"], abs=1e-15)
    # the Butterly layer sets its own course and speed law: the fix gives it nothing
    assert dict(scene.layers[1].params) == dict(given.layers[1].params)


def test_a_layer_and_defaults_win_over_the_fix(tmp_path):
    (tmp_path / "track.gpx").write_text(TRACK_GPX)
    text = from_file(SHIP, 'fix_file = "track.gpx"').replace("v0 = 5.0", "v0 = 7.0")
    scene = parse_scene(text, source="s.toml", directory=tmp_path)
    assert scene.layers[0].params["v0"] == 7.0


def test_course_from_the_last_two_points(tmp_path):
    (tmp_path / "t.csv").write_text("time,lat,lon\n2026-11-24T05:39:00Z,60.4505,4.6003\n2026-11-24T05:40:00Z,60.45,4.60\n")
    text = from_file(SHIP, 'fix_file = "t.csv"').replace("v0 = 5.0\n", "").replace("heading_deg = 200.0", "")
    scene = parse_scene(text, source="s.toml", directory=tmp_path)
    fix = bg.read_fix(tmp_path / "t.csv")
    assert 0.5 < fix.speed < 1.5  # about 60 m in 60 s
    assert scene.layers[0].params["v0"] == fix.speed
    assert scene.geo.time == fix.time


@pytest.mark.parametrize("geo, message", [
    ('fix_file = "track.gpx"\norigin_latlon = [60.0, 4.0]', 'geo.origin_latlon = [60.0, 4.0]: given with geo.fix_file'),
    ('fix_file = "track.gpx"\ntime = "2026-11-24T05:40:00Z"', 'geo.time = "2026-11-24T05:40:00Z": given with geo.fix_file'),
    ('fix_file = "nope.gpx"', 'geo.fix_file = "nope.gpx": DIR/nope.gpx: no such file'),
    ('fix_file = ""', 'geo.fix_file = "": expected a file name (relative to the scene file)'),
    ('fix_file = "bad.csv"', 'geo.fix_file = "bad.csv": line 3: time 2026-11-24T05:00:00Z is not after 2026-11-24T05:00:00Z '
                             '(line 2); a track\'s times must strictly increase'),
    ('fix_file = "one.csv"', 'layers.cat: heading: geo.fix_file ("one.csv") gives no course (one point, or its last two '
                             'at one place); give heading (or heading_deg) in [layers.cat] or [defaults]'),
    ('fix_file = "track.gpx"\nfix_mmsi = 12', 'geo.fix_mmsi = 12: selects AIS reports of an NMEA file; this is GPX'),
    ('fix_mmsi = 12\norigin_latlon = [60.0, 4.0]', "geo.fix_mmsi = 12: picks a vessel of geo.fix_file's AIS reports"),
    ('fix_file = "track.gpx"\nfix_mmsi = 1e9', "geo.fix_mmsi = 1000000000.0: expected a vessel's MMSI"),
    ('bearings_file = "b.csv"\norigin_latlon = [60.0, 4.0]', 'geo.bearings_file: no layer takes bearings'),
    ('fix_fiel = "track.gpx"', 'geo.fix_fiel: unknown key; did you mean "fix_file"? allowed:'),
])
def test_bad_input_files(tmp_path, geo, message):
    (tmp_path / "track.gpx").write_text(TRACK_GPX)
    (tmp_path / "bad.csv").write_text("time,lat,lon\n2026-11-24T05:00:00Z,60,5\n2026-11-24T05:00:00Z,60,5\n")
    (tmp_path / "one.csv").write_text("time,lat,lon,speed_mps\n2026-11-24T05:00:00Z,60,5,3.0\n")
    (tmp_path / "b.csv").write_text("station_lat,station_lon,bearing_deg,sigma_deg,time\n60,5,10,1,2026-11-24T05:00:00Z\n")
    text = from_file(SHIP, geo).replace("heading_deg = 200.0", "")
    with pytest.raises(bg.BananagridError) as info:
        parse_scene(text, source="s.toml", directory=tmp_path)
    assert str(info.value).startswith("s.toml: " + message.replace("DIR", str(tmp_path))), str(info.value)
    assert "\n" not in str(info.value)


def test_a_value_from_the_fix_the_model_refuses_names_the_file(tmp_path):
    (tmp_path / "still.csv").write_text("time,lat,lon,speed_mps,course_deg\n2026-11-24T05:00:00Z,60,5,0,10\n")
    text = from_file(SHIP, 'fix_file = "still.csv"').replace("v0 = 5.0\n", "")
    with pytest.raises(bg.BananagridError, match=r'^s\.toml: geo\.fix_file \("still\.csv"\): speed \(m/s\) = 0\.0: '
                                                 r'must be > 0$'):
        parse_scene(text, source="s.toml", directory=tmp_path)


def test_bearings_file_gives_the_stations_bearings_and_errors(tmp_path):
    (tmp_path / "b.csv").write_text("station,station_lat,station_lon,bearing_deg,sigma_deg,time\n"
                                    "Marstein,60.1279,5.0086,317.4,1.0,2026-11-24T06:10:00Z\n"
                                    "Hellisoy,60.7517,4.7131,206.7,1.5,2026-11-24T06:10:00Z\n")
    given = parse_scene(BEARING, source="b.toml")
    doc = BEARING.replace('time = "2026-11-24T06:10:00Z"\n', 'bearings_file = "b.csv"\n')
    doc = re.sub(r"\[defaults\]\n(.*\n){3}", "", doc)
    assert "sensors_latlon" not in doc
    scene = parse_scene(doc, source="b.toml", directory=tmp_path)
    assert scene.geo.identity() == given.geo.identity()  # the bearings' time is the scene's
    for layer, expected in zip(scene.layers, given.layers):
        np.testing.assert_allclose(layer.params["sensors"], expected.params["sensors"], rtol=0, atol=1e-9)  # m
        # 1e-15 rad: degrees to radians and back in another order of operations
        np.testing.assert_allclose(layer.params["bearings"], expected.params["bearings"], rtol=0, atol=1e-15)
        np.testing.assert_allclose(layer.params["sigmas"], expected.params["sigmas"], rtol=0, atol=1e-15)


def test_paths_are_relative_to_the_scene_file(tmp_path, monkeypatch):
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "track.gpx").write_text(TRACK_GPX)
    (tmp_path / "ship.toml").write_text(from_file(SHIP, 'fix_file = "data/track.gpx"'))
    monkeypatch.chdir("/")
    assert bg.load_scene(tmp_path / "ship.toml").geo.lat == 60.45


# --- unknown keys: the nearest valid one -------------------------------------------------------


def _minimal(kind: str) -> str:
    return ('[scene]\nname = "s"\n[grid]\nx = [-100.0, 100.0]\ny = [-100.0, 100.0]\nstep = 10.0\n'
            f'[layers.a]\nmodel = "{kind}"\n')


def _tables():
    """(name, allowed keys, a scene text with ``{line}`` where a key of that table goes)."""
    grid = _minimal("cat")
    yield "top", TOP_KEYS, "{line}\n" + grid
    yield "scene", SCENE_KEYS, grid.replace('name = "s"\n', 'name = "s"\n{line}\n')
    yield "grid", GRID_KEYS, grid.replace("step = 10.0\n", "step = 10.0\n{line}\n")
    yield "geo", GEO_KEYS, "[geo]\norigin_latlon = [60.0, 5.0]\n{line}\n" + grid
    switches = tuple(n for k in MODEL_KINDS.values() for n in k.scene.options)
    yield "output", (*OUTPUT_KEYS, *switches), grid + "[output]\n{line}\n"
    cat = grid + "v0 = 5.0\nt = 10.0\nsigma_a = 1.0\nsigma_omega = 0.1\n"  # [radial] is read after the layers
    yield "radial", RADIAL_KEYS, cat + "[radial]\n{line}\n"
    every = tuple(dict.fromkeys(k for kind in MODEL_KINDS.on("grid").values() for k in kind.scene.key_names))
    yield "defaults", every, grid + "[defaults]\n{line}\n"
    for name, kind in MODEL_KINDS.on("grid").items():
        yield f"layers ({name})", ("model", *kind.scene.key_names), _minimal(name) + "{line}\n"
    room = (ROOT / "scenes" / "room_uniform.toml").read_text()
    yield "array", presence.ARRAY_KEYS, room.replace("h = 1.8\n", "h = 1.8\n{line}\n")
    yield "room", presence.ROOM_KEYS, room.replace("z = [-3.0, 0.0]\n", "z = [-3.0, 0.0]\n{line}\n")
    yield "presence", ("kind",), room.replace('kind = "uniform"\n', 'kind = "uniform"\n{line}\n')
    yield "output (array)", presence.OUTPUT_KEYS, room + "[output]\n{line}\n"
    yield "top (array)", presence.TOP_KEYS, "{line}\n" + room
    mixture = (ROOT / "scenes" / "room_mixture.toml").read_text()
    yield "presence (mixture)", ("kind", "components"), mixture.replace('kind = "mixture"\n', 'kind = "mixture"\n{line}\n')
    yield ("a mixture's component", ("weight", "mean", "cov", "sd_x", "sd_y", "rho"),
           mixture.replace("rho = 0.3\n", "rho = 0.3\n{line}\n"))


TABLES = list(_tables())


@pytest.mark.parametrize("table, allowed, template", TABLES, ids=[t[0] for t in TABLES])
def test_every_key_with_one_letter_changed_names_the_nearest(table, allowed, template):
    """Each valid key of each table, each letter in turn replaced: the message names the key
    difflib finds nearest (the original, unless another valid key is as near), in one line."""
    checked = 0
    for key in allowed:
        for k in range(len(key)):
            typo = key[:k] + ("q" if key[k] != "q" else "z") + key[k + 1:]
            if typo in allowed:
                continue
            text = template.replace("{line}", f"{typo} = 1")
            tomllib.loads(text)  # the typo is a key where it was put
            with pytest.raises(bg.BananagridError) as info:
                parse_scene(text, source="s.toml")
            message = str(info.value)
            assert "\n" not in message and f"{typo}: unknown key" in message, message
            best = difflib.get_close_matches(typo, list(allowed), n=1)
            if best:
                assert f'did you mean "{best[0]}"?' in message, message
                # the original key is suggested unless another is at least as near
                nearer = [a for a in allowed if a != key and difflib.SequenceMatcher(None, typo, a).ratio()
                          >= difflib.SequenceMatcher(None, typo, key).ratio()]
                if not nearer:
                    assert best[0] == key
                checked += 1
            else:
                assert "did you mean" not in message
    assert checked > 0 or all(len(key) < 3 for key in allowed)


def test_the_example_of_a_mistyped_key():
    text = _minimal("cat") + "v0 = 5.0\nt = 10.0\nsigma_a = 1.0\nsigma_omgea = 0.1\n"
    with pytest.raises(bg.BananagridError, match=r'^s\.toml: layers\.a\.sigma_omgea: unknown key \(model "cat"\); '
                                                 r'did you mean "sigma_omega"\? allowed: model, v0'):
        parse_scene(text, source="s.toml")


def test_docs_name_every_geo_key():
    doc = (ROOT / "docs" / "scenes.md").read_text()
    assert [key for key in GEO_KEYS if f"| `{key}` |" not in doc] == []


def test_fix_mmsi_picks_a_vessel_of_an_ais_log(tmp_path):
    # two vessels (pyais's published decodes, see tests/geo/test_inputs.py), received at UNIX times
    (tmp_path / "ais.nmea").write_text("!AIVDM,1,1,,B,15M67FC000G?ufbE`FepT@3n00Sa,0*5C,1420070398\n"
                                       "!AIVDM,1,1,,A,35NSH95001G?wopE`beasVk@0E5:,0*6F,1420070460\n")
    # the Butterly layer's mean lies off Bergen, 8,000 km away: the CAT layer alone
    text = from_file(SHIP, 'fix_file = "ais.nmea"\nfix_mmsi = 367581220').split("[layers.butterly]")[0]
    scene = parse_scene(text, source="s.toml", directory=tmp_path)
    assert round(scene.geo.lat, 4) == 37.8107 and round(scene.geo.lon, 4) == -122.3343
    assert scene.geo.time.isoformat() == "2015-01-01T00:00:40+00:00"
    with pytest.raises(bg.BananagridError, match=r'geo\.fix_mmsi = 1: no AIS position report of it \(vessels: '
                                                 r'366053209, 367581220\)'):
        parse_scene(text.replace("fix_mmsi = 367581220", "fix_mmsi = 1"), source="s.toml", directory=tmp_path)
    with pytest.raises(bg.BananagridError, match=r'AIS reports of 2 vessels \(366053209, 367581220\); give geo\.fix_mmsi, '
                                                 'the MMSI of the vessel wanted$'):
        parse_scene(text.replace("fix_mmsi = 367581220", ""), source="s.toml", directory=tmp_path)


def test_a_scene_with_a_fix_file_runs(tmp_path, capsys):
    from bananagrid.cli import main

    (tmp_path / "track.gpx").write_text(TRACK_GPX)
    text = from_file(SHIP, 'fix_file = "track.gpx"').replace("v0 = 5.0\n", "").replace("heading_deg = 200.0", "")
    text = text.split("[layers.butterly]")[0].replace("times = [300.0, 600.0, 900.0]", "times = [300.0]")
    (tmp_path / "ship.toml").write_text(text)
    assert main(["run", str(tmp_path / "ship.toml"), "--out", str(tmp_path / "out"), "--step", "250", "--quiet"]) == 0
    assert (tmp_path / "out" / "geo_ship.rrd").is_file()
    assert "geo_ship" in capsys.readouterr().out
