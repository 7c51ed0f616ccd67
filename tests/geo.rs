//! Georeferenced outputs read back by third-party readers: the COG GeoTIFF and the PNG world
//! files through GDAL (the `rasterio` wheel, with `rio-cogeo`'s validator and pyproj), in a
//! Python environment this test builds under `target/geo-py` from the package registry. Without
//! Python or the registry the test says it skips.

use crate::common::*;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

mod qmesh;

/// The Python interpreter of `target/geo-py/venv`, with rasterio, rio-cogeo, pyproj and
/// jsonschema; None (after saying why) when that is impossible.
fn python_env() -> Option<PathBuf> {
    python_venv(
        "geo-py",
        &["rasterio", "rio-cogeo", "pyproj", "jsonschema"],
        "rasterio",
    )
}

/// Asserts that every manifest in `manifests` is valid against docs/manifest.schema.json
/// (through the Python environment's `jsonschema`).
pub(crate) fn assert_schema_valid(py: &Path, manifests: &[PathBuf]) {
    let o = Command::new(py)
        .arg(repo().join("tests/geo/validate_manifest.py"))
        .arg(repo().join("docs/manifest.schema.json"))
        .args(manifests)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "manifest not valid against docs/manifest.schema.json:\n{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Runs terratile on `input` with the GeoTIFF on and returns the output directory.
fn run_geo(dir: &Path, input: &Path, extra: &str) -> PathBuf {
    let toml = format!(
        "[input]\npaths = [{:?}]\n{extra}\n[output]\ndir = \"out\"\ngeotiff = true\ngeotiff_tiles = true\nraw = false\n\
         relief = false\nwireframe = false\nmeshes = []\n",
        input.to_str().unwrap()
    );
    std::fs::write(dir.join("p.toml"), toml).unwrap();
    terratile(dir, &["run", "p.toml", "--quiet"]).ok();
    dir.join("out")
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// The EXR tiles' heights reassembled, north row first (the GeoTIFF's order).
fn exr_grid(out: &Path, m: &Value) -> (usize, usize, Vec<f32>) {
    let cols = m["grid"]["samples"][0].as_u64().unwrap() as usize;
    let rows = m["grid"]["samples"][1].as_u64().unwrap() as usize;
    let mut g = vec![f32::INFINITY; cols * rows];
    for t in m["tiles"].as_array().unwrap() {
        let image = exr::prelude::read_first_flat_layer_from_file(
            out.join(t["files"]["exr"].as_str().unwrap()),
        )
        .unwrap();
        let layer = image.layer_data;
        let w = layer.size.width();
        let h = layer.size.height();
        let ch = layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.to_string() == "height")
            .unwrap();
        let v: Vec<f32> = ch.sample_data.values_as_f32().collect();
        let n = |k: &str, i: usize| t[k][i].as_u64().unwrap() as usize;
        let (ox, oy) = (n("grid_offset", 0), n("grid_offset", 1));
        let (vw, vh) = (n("valid", 0), n("valid", 1));
        for j in 0..vh {
            // EXR row 0 is the tile's north row; grid row r counts from the north too.
            let src_row = h - 1 - j;
            let dst_row = rows - 1 - (oy + j);
            for i in 0..vw {
                g[dst_row * cols + ox + i] = v[src_row * w + i];
            }
        }
    }
    (cols, rows, g)
}

/// One survey through the GeoTIFF and PNG outputs, read back by GDAL.
fn check_survey(file: &str, extra: &str, expected_crs: &str) {
    let Some(input) = data_file(file) else { return };
    let Some(py) = python_env() else { return };
    let d = tempfile::tempdir().unwrap();
    let out = run_geo(d.path(), &input, extra);
    let m: Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    let values = d.path().join("dem.f32");
    let tile_values = d.path().join("tiles.f32");
    let o = Command::new(&py)
        .arg(repo().join("tests/geo/check_outputs.py"))
        .arg(&out)
        .arg(expected_crs)
        .arg(&values)
        .arg(&tile_values)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: Value = serde_json::from_slice(&o.stdout).unwrap();
    let ctx = format!("{file}: {r:#}");
    assert_schema_valid(&py, &[out.join("manifest.json")]);
    // The manifest names the whole grid's GeoTIFF.
    assert_eq!(m["grid_files"]["geotiff"], "dem.tif");
    // The manifest's WGS 84 bounds hold the GeoTIFF's extent, reprojected.
    let b: Vec<f64> = m["geographic"]["wgs84_bounds"]
        .as_array()
        .unwrap_or_else(|| panic!("no wgs84_bounds: {}", m["geographic"]))
        .iter()
        .map(f)
        .collect();
    assert!(
        b[0] < b[2] && b[1] < b[3] && b[0] >= -180.0 && b[3] <= 90.0,
        "{b:?}"
    );
    assert_eq!(m["geographic"]["footprint"]["type"], "Polygon");
    // The CRS GDAL reads is the input's.
    assert_eq!(r["crs_equals"], true, "{ctx}");
    // Geotransform: the grid's outer north-west corner and its spacing.
    let g = &m["grid"];
    let (cx, cy) = (f(&g["cell_size"][0]), f(&g["cell_size"][1]));
    let rows = g["samples"][1].as_u64().unwrap() as f64;
    let want = [
        cx,
        0.0,
        f(&g["corner"][0]),
        0.0,
        -cy,
        f(&g["corner"][1]) + rows * cy,
    ];
    let got: Vec<f64> = r["transform"].as_array().unwrap().iter().map(f).collect();
    assert_eq!(got, want, "{ctx}");
    assert_eq!(r["dtype"], "float32");
    assert_eq!(r["blocks"][0], serde_json::json!([512, 512]), "{ctx}");
    assert_eq!(r["predictor"], "3", "{ctx}");
    assert_eq!(r["cog_valid"], true, "{ctx}");
    // Nodata: NaN exactly when the grid keeps holes.
    let holes = g["holes"].as_u64().unwrap();
    assert_eq!(r["nodata"].as_str() == Some("nan"), holes > 0, "{ctx}");
    // Values: the EXR tiles' f32 heights, bit for bit.
    let (cols, nrows, exr) = exr_grid(&out, &m);
    assert_eq!(r["size"], serde_json::json!([cols, nrows]));
    let bytes = std::fs::read(&values).unwrap();
    assert_eq!(bytes.len(), 4 * cols * nrows);
    let mut differ = 0;
    for (k, c) in bytes.chunks_exact(4).enumerate() {
        let v = f32::from_le_bytes(c.try_into().unwrap());
        if v.to_bits() != exr[k].to_bits() {
            differ += 1;
        }
    }
    assert_eq!(
        differ, 0,
        "{file}: {differ} values differ from the EXR tiles"
    );
    // Every per-tile GeoTIFF, read by GDAL: the input's CRS, the geotransform of the tile's
    // valid extent as the manifest places it (outer north-west corner from `grid_offset`, and
    // the centre of its south-west pixel at the tile's `origin`), nodata NaN exactly when the
    // tile has holes, the band offset of dem.tif, and the tile's valid extent of the EXR
    // tiles bit for bit.
    let tifs = r["tifs"].as_array().unwrap();
    let mts = m["tiles"].as_array().unwrap();
    assert_eq!(tifs.len(), mts.len(), "{ctx}");
    let tile_bytes = std::fs::read(&tile_values).unwrap();
    let mut tile_vals = tile_bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()));
    for (t, mt) in tifs.iter().zip(mts) {
        let name = t["tif"].as_str().unwrap();
        assert_eq!(Some(name), mt["files"]["tif"].as_str());
        let n = |k: &str, i: usize| mt[k][i].as_u64().unwrap() as usize;
        let (w, h) = (n("valid", 0), n("valid", 1));
        assert_eq!(t["size"], serde_json::json!([w, h]), "{name}");
        assert_eq!(t["dtype"], "float32", "{name}");
        assert_eq!(t["crs_equals"], true, "{name}: {t}");
        assert_eq!(t["offset"], r["offset"], "{name}");
        let has_holes = mt["holes"].as_u64().unwrap() > 0;
        assert_eq!(t["nodata"].as_str() == Some("nan"), has_holes, "{name}");
        let west = f(&g["corner"][0]) + n("grid_offset", 0) as f64 * cx;
        let north = f(&g["corner"][1]) + (n("grid_offset", 1) + h) as f64 * cy;
        let got: Vec<f64> = t["transform"].as_array().unwrap().iter().map(f).collect();
        assert_eq!(got, [cx, 0.0, west, 0.0, -cy, north], "{name}");
        let sw = [west + 0.5 * cx, north - (h as f64 - 0.5) * cy];
        for a in 0..2 {
            let want = f(&mt["origin"][a]);
            assert!((sw[a] - want).abs() < 1e-6, "{name}: {} vs {want}", sw[a]);
        }
        let mut differ = 0;
        for j in 0..h {
            // Both north row first; the tile's north row is grid row (from the north)
            // rows − (offset + h).
            let gr = nrows - (n("grid_offset", 1) + h) + j;
            for i in 0..w {
                let want = exr[gr * cols + n("grid_offset", 0) + i];
                let got = tile_vals.next().expect("a value per pixel");
                differ += usize::from(got.to_bits() != want.to_bits());
            }
        }
        assert_eq!(
            differ, 0,
            "{name}: {differ} values differ from the EXR tiles"
        );
    }
    assert!(tile_vals.next().is_none(), "more tile values than pixels");
    // Every PNG heightmap lands where the manifest puts its tile.
    let tiles = r["tiles"].as_array().unwrap();
    assert_eq!(tiles.len(), m["tiles"].as_array().unwrap().len());
    for (t, mt) in tiles.iter().zip(m["tiles"].as_array().unwrap()) {
        assert_eq!(t["crs_equals"], true, "{ctx}");
        for a in 0..2 {
            let (got, want) = (f(&t["sw_sample"][a]), f(&mt["origin"][a]));
            assert!((got - want).abs() < 1e-6, "{}: {got} vs {want}", t["png"]);
        }
        assert_eq!(f(&t["pixel"][0]), cx);
        assert_eq!(f(&t["pixel"][1]), -cy);
    }
}

/// BC Albers by EPSG code, with CGVD28 heights (GeoTIFF keys in the LAZ).
#[test]
fn geotiff_bc_albers_with_vertical_datum() {
    check_survey("lidar/bcts_3.laz", "", "EPSG:3005+5713");
    let Some(input) = data_file("lidar/bcts_3.laz") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let out = run_geo(d.path(), &input, "");
    let m: Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["geographic"]["vertical_datum"]["epsg"], 5713);
    assert_eq!(m["geographic"]["vertical_datum"]["name"], "CGVD28");
}

/// Oregon Lambert in international feet: an ESRI-style WKT without EPSG code.
#[test]
fn geotiff_oregon_lambert_feet_wkt() {
    let wkt = repo().join("target/geo-py/autzen.wkt");
    let Some(input) = data_file("lidar/autzen_trim.las") else {
        return;
    };
    let info = terratile(&repo(), &["info", input.to_str().unwrap(), "--json"]);
    let v: Value = serde_json::from_str(&info.stdout).unwrap();
    let _ = std::fs::create_dir_all(wkt.parent().unwrap());
    std::fs::write(&wkt, v[0]["source"]["crs"]["wkt"].as_str().unwrap()).unwrap();
    check_survey("lidar/autzen_trim.las", "", &format!("@{}", wkt.display()));
}

/// MTM zone 7 with holes kept (the lake): NaN nodata.
#[test]
fn geotiff_mtm_with_holes() {
    check_survey(
        "lidar/Topography.laz",
        "[fill]\nfallback = \"nodata\"\nradius = 2\n",
        "EPSG:2949",
    );
}

/// The default job's manifest (no real data needed), with and without meshes, satisfies the
/// schema; a manifest missing a required field or with a wrong type does not (the check
/// can fail).
#[test]
fn manifest_schema_validates_written_manifests() {
    let Some(py) = python_env() else { return };
    let d = default_job();
    terratile(d.path(), &["run", "--quiet"]).ok();
    let good = d.path().join("out/manifest.json");
    let mut m: Value = serde_json::from_slice(&std::fs::read(&good).unwrap()).unwrap();
    let e = default_job();
    let p = e.path().join("pipeline.toml");
    let text = std::fs::read_to_string(&p)
        .unwrap()
        .replacen("meshes = [\"glb\"]", "meshes = []", 1)
        .replacen("wireframe = true", "wireframe = false", 1)
        .replacen("exr = true", "exr = false", 1);
    std::fs::write(&p, text).unwrap();
    terratile(e.path(), &["run", "--quiet"]).ok();
    assert_schema_valid(&py, &[good.clone(), e.path().join("out/manifest.json")]);
    m.as_object_mut().unwrap().remove("grid");
    m["tiling"]["exr_channel_info"][0]["sample_type"] = Value::from("f16");
    let bad = d.path().join("bad.json");
    std::fs::write(&bad, serde_json::to_vec(&m).unwrap()).unwrap();
    let o = Command::new(&py)
        .arg(repo().join("tests/geo/validate_manifest.py"))
        .arg(repo().join("docs/manifest.schema.json"))
        .arg(&bad)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(
        !o.status.success()
            && said.contains("'grid' is a required property")
            && said.contains("sample_type"),
        "{said}"
    );
}

/// Our WGS 84 corners of every real survey's bounding box within 1 mm of PROJ's (pyproj,
/// reference values made once by tests/geo/make_reference.py, committed with their source),
/// and back to the CRS within 1 mm.
#[test]
fn reprojection_matches_pyproj_within_a_millimetre() {
    use terratile::geo::{crs_from_key, ToWgs84};
    let r: Value = serde_json::from_slice(
        &std::fs::read(repo().join("tests/geo/wgs84_reference.json")).unwrap(),
    )
    .unwrap();
    let autzen_wkt = r#"PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic",GEOGCS["GCS_North_American_1983_HARN",DATUM["NAD83_High_Accuracy_Regional_Network",SPHEROID["GRS_1980",6378137,298.257222101,AUTHORITY["EPSG","7019"]],AUTHORITY["EPSG","6152"]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic_2SP"],PARAMETER["standard_parallel_1",43],PARAMETER["standard_parallel_2",45.5],PARAMETER["latitude_of_origin",41.75],PARAMETER["central_meridian",-120.5],PARAMETER["false_easting",1312335.958005249],PARAMETER["false_northing",0],UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]]]"#;
    let surveys = r["surveys"].as_array().unwrap();
    assert_eq!(surveys.len(), 5);
    for s in surveys {
        let crs = match s["crs"].as_str().unwrap() {
            "WKT" => terratile::points::Crs {
                wkt: Some(autzen_wkt.into()),
                epsg: None,
                geotiff: None,
                unit: None,
                vertical: None,
            },
            code => crs_from_key(code).unwrap(),
        };
        let t = ToWgs84::new(&crs).unwrap();
        for c in s["corners"].as_array().unwrap() {
            let (x, y) = (f(&c["xy"][0]), f(&c["xy"][1]));
            let (lon, lat) = (f(&c["lonlat"][0]), f(&c["lonlat"][1]));
            let [ol, ob] = t.forward(x, y).unwrap();
            // Metres on the ground per degree, generously (1 mm ≈ 9e-9° of latitude).
            let dn = (ob - lat) * 111_320.0;
            let de = (ol - lon) * 111_320.0 * lat.to_radians().cos();
            assert!(
                dn.hypot(de) < 1e-3,
                "{}: {x} {y}: {dn} m N, {de} m E",
                s["name"]
            );
            let [bx, by] = t.inverse(ol, ob).unwrap();
            let unit = crs.metres_per_unit();
            let back = ((bx - x) * unit).hypot((by - y) * unit);
            assert!(back < 1e-3, "{}: round trip {back} m", s["name"]);
        }
    }
}
