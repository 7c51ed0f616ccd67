"""Makes tests/geo/wgs84_reference.json: WGS 84 longitude/latitude of the bounding-box corners
of every real survey, computed by pyproj (PROJ), once; the test compares terratile's
reprojection (proj4rs) with them.

The source CRS is given to PROJ as the same definition terratile uses (the EPSG table's PROJ
string, or the file's WKT), so that both apply the same datum shift: the comparison tests the
implementation, not the choice among EPSG's transformations. `default_shift_m` records how far
PROJ's own default choice (EPSG code to EPSG:4326 with its database) lands from that, for the
record.

usage: make_reference.py OUT_JSON   (run with the venv of tests/geo.rs; needs pyproj)
"""
import json
import sys

import pyproj
from pyproj import CRS, Transformer

AUTZEN_WKT = open("target/geo-py/autzen.wkt", encoding="utf-8").read()
SURVEYS = [
    # name, crs as terratile sees it, its PROJ string, bbox (min x, min y, max x, max y)
    ("CSite4_orig-utm", "EPSG:32632", "+proj=utm +zone=32 +datum=WGS84 +units=m +no_defs",
     (513119.49, 5403189.74, 513630.09, 5403762.83)),
    ("bcts_3", "EPSG:3005",
     "+proj=aea +lat_1=50 +lat_2=58.5 +lat_0=45 +lon_0=-126 +x_0=1000000 +y_0=0 +datum=NAD83 +units=m +no_defs",
     (885026.3, 629700.0, 885223.96, 629999.99)),
    ("Topography", "EPSG:2949",
     "+proj=tmerc +lat_0=0 +lon_0=-70.5 +k=0.9999 +x_0=304800 +y_0=0 +ellps=GRS80 +towgs84=0,0,0,0,0,0,0 +units=m +no_defs",
     (273357.14, 5274357.14, 273642.86, 5274642.85)),
    ("ahn3 (RD New, given as [input] crs)", "EPSG:28992",
     "+proj=sterea +lat_0=52.15616055555555 +lon_0=5.38763888888889 +k=0.9999079 +x_0=155000 +y_0=463000 +ellps=bessel +towgs84=565.2369,50.0087,465.658,-0.406857,0.350733,-1.87035,4.0812 +units=m +no_defs",
     (84000.0, 445000.0, 86000.0, 447000.0)),
    # The file's ESRI WKT as proj4wkt turns it into a PROJ string (no TOWGS84 in the WKT: a
    # null shift); PROJ's default for the WKT itself uses its NAD83(HARN) transformation.
    ("autzen_full", "WKT",
     "+proj=lcc +lat_1=43 +lat_2=45.5 +lat_0=41.75 +lon_0=-120.5 +x_0=400000 +y_0=0 +to_meter=0.3048 +a=6378137 +rf=298.257222101 +towgs84=0,0,0,0,0,0,0",
     (635577.79, 848882.15, 639003.73, 853537.66)),
]
out = {"source": f"pyproj {pyproj.__version__}, PROJ {pyproj.proj_version_str}", "surveys": []}
for name, crs, p4, (x0, y0, x1, y1) in SURVEYS:
    src = CRS.from_proj4(p4)
    t = Transformer.from_crs(src, "EPSG:4326", always_xy=True)
    default = Transformer.from_crs(
        CRS.from_wkt(AUTZEN_WKT) if crs == "WKT" else CRS.from_user_input(crs), "EPSG:4326", always_xy=True
    )
    corners = []
    shift = 0.0
    for x, y in [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]:
        lon, lat = t.transform(x, y)
        dlon, dlat = default.transform(x, y)
        geod = pyproj.Geod(ellps="WGS84")
        shift = max(shift, geod.inv(lon, lat, dlon, dlat)[2])
        corners.append({"xy": [x, y], "lonlat": [lon, lat]})
    out["surveys"].append(
        {"name": name, "crs": crs, "corners": corners, "default_shift_m": round(shift, 4)}
    )
json.dump(out, open(sys.argv[1], "w", encoding="utf-8"), indent=1)
