"""Reads terratile's georeferenced outputs with GDAL (through rasterio) and reports what it
sees as JSON on stdout, for tests/geo.rs to compare with the manifest and the EXR tiles.

usage: check_outputs.py OUT_DIR EXPECTED_CRS VALUES_FILE TILE_VALUES_FILE
  EXPECTED_CRS: anything pyproj's CRS.from_user_input takes ("EPSG:3005+5713"), or
                @FILE holding a WKT.
  VALUES_FILE:  where the GeoTIFF's band 1 goes, as raw little-endian f32, north row first.
  TILE_VALUES_FILE: where band 1 of every per-tile GeoTIFF goes (manifest order, each north
                row first), the same way.
"""
import json
import sys

import rasterio
from pyproj import CRS
from rio_cogeo.cogeo import cog_validate

out, expected, values_file, tile_values_file = sys.argv[1:5]
if expected.startswith("@"):
    expected = open(expected[1:], encoding="utf-8").read()
want = CRS.from_user_input(expected)
# The PNGs' .prj files carry the horizontal CRS only.
want_h = want.sub_crs_list[0] if want.is_compound else want
manifest = json.load(open(f"{out}/manifest.json", encoding="utf-8"))
report = {}

with rasterio.open(f"{out}/dem.tif") as src:
    report["size"] = [src.width, src.height]
    report["dtype"] = src.dtypes[0]
    report["transform"] = list(src.transform)[:6]
    report["crs_equals"] = CRS.from_wkt(src.crs.to_wkt()).equals(want)
    report["crs"] = src.crs.to_wkt()
    report["epsg"] = src.crs.to_epsg()
    report["nodata"] = None if src.nodata is None else repr(src.nodata)
    report["offset"] = src.offsets[0]
    report["overviews"] = src.overviews(1)
    report["blocks"] = [list(b) for b in src.block_shapes]
    report["compression"] = str(src.compression)
    report["predictor"] = src.tags(ns="IMAGE_STRUCTURE").get("PREDICTOR")
    band = src.read(1)
    band.astype("<f4").tofile(values_file)
valid, errors, warnings = cog_validate(f"{out}/dem.tif", quiet=True)
report["cog_valid"] = valid
report["cog_errors"] = errors
report["cog_warnings"] = warnings

tiles = []
for t in manifest["tiles"]:
    png = t["files"].get("png")
    if png is None:
        continue
    with rasterio.open(f"{out}/{png}") as src:
        n = src.height
        # The centre of the south-west pixel: the tile's first sample.
        x, y = src.transform * (0.5, n - 0.5)
        tiles.append(
            {
                "png": png,
                "sw_sample": [x, y],
                "pixel": [src.transform.a, src.transform.e],
                "crs_equals": src.crs is not None
                and CRS.from_wkt(src.crs.to_wkt()).equals(want_h),
            }
        )
report["tiles"] = tiles

# The per-tile GeoTIFFs (geotiff_tiles = true), through GDAL as well.
tifs = []
with open(tile_values_file, "wb") as values:
    for t in manifest["tiles"]:
        tif = t["files"].get("tif")
        if tif is None:
            continue
        with rasterio.open(f"{out}/{tif}") as src:
            tifs.append(
                {
                    "tif": tif,
                    "size": [src.width, src.height],
                    "dtype": src.dtypes[0],
                    "transform": list(src.transform)[:6],
                    "crs_equals": CRS.from_wkt(src.crs.to_wkt()).equals(want),
                    "nodata": None if src.nodata is None else repr(src.nodata),
                    "offset": src.offsets[0],
                }
            )
            src.read(1).astype("<f4").tofile(values)
report["tifs"] = tifs
print(json.dumps(report))
