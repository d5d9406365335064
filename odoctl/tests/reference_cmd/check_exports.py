"""Reads `odoctl reference --to geojson` and `--to gpx` output with independent readers (the
standard `json` module with RFC 7946 structure checks, and `gpxpy`) and compares every point
with the expected CSV.

Usage: check_exports.py TRACK.geojson TRACK.gpx EXPECTED.csv
EXPECTED.csv: lat,lon,height,utc (ISO 8601 with Z), one row per used epoch.
"""

import csv
import datetime
import json
import sys

import gpxpy


def main():
    geojson_path, gpx_path, expected_path = sys.argv[1:4]
    with open(expected_path, newline="") as f:
        want = list(csv.DictReader(f))
    with open(geojson_path) as f:
        doc = json.load(f)
    assert doc["type"] == "FeatureCollection", doc["type"]
    assert "crs" not in doc, "RFC 7946 has no crs member"
    feature = doc["features"][0]
    assert feature["type"] == "Feature"
    geom = feature["geometry"]
    assert geom["type"] == "LineString"
    coords = geom["coordinates"]
    assert len(coords) == len(want), (len(coords), len(want))
    times = feature["properties"]["coordTimes"]
    for c, w, t in zip(coords, want, times):
        # RFC 7946: longitude, latitude[, height].
        assert abs(c[0] - float(w["lon"])) < 1e-8, (c, w)
        assert abs(c[1] - float(w["lat"])) < 1e-8, (c, w)
        assert abs(c[2] - float(w["height"])) < 5e-3, (c, w)
        assert t == w["utc"], (t, w)
    with open(gpx_path) as f:
        gpx = gpxpy.parse(f)
    assert gpx.version == "1.1", gpx.version
    points = [p for trk in gpx.tracks for seg in trk.segments for p in seg.points]
    assert len(points) == len(want), (len(points), len(want))
    for p, w in zip(points, want):
        assert abs(p.latitude - float(w["lat"])) < 1e-8, (p, w)
        assert abs(p.longitude - float(w["lon"])) < 1e-8, (p, w)
        assert abs(p.elevation - float(w["height"])) < 5e-3, (p, w)
        utc = datetime.datetime.strptime(w["utc"], "%Y-%m-%dT%H:%M:%S.%fZ").replace(
            tzinfo=datetime.timezone.utc
        )
        assert p.time.utcoffset() == datetime.timedelta(0), p.time
        assert abs((p.time - utc).total_seconds()) < 1e-3, (p.time, utc)
    print(f"ok: {len(points)} points")


if __name__ == "__main__":
    main()
