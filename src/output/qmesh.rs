//! The Cesium terrain tileset: `terrain/layer.json` and `terrain/{z}/{x}/{y}.terrain`, each a
//! gzip-compressed quantized-mesh-1.0 tile (as Cesium's servers deliver it) with edge index
//! lists (clients hang skirts from them) and the oct-encoded vertex normals extension.
//!
//! The byte format (header, zig-zag delta vertex streams, high-water-mark indices, edge
//! lists, extension framing, oct encoding, gzip) is the `quantized-mesh` crate's; this file
//! quantizes our tiles for it and completes the header from the actual vertices.

use crate::error::{Error, Result};
use crate::geo::tin::Q;
use crate::geo::tms::{TerrainTile, Tileset};
use quantized_mesh::coords::geodetic_to_ecef;
use quantized_mesh::{
    EdgeIndices, EncodeOptions, QuantizedMeshEncoder, QuantizedMeshHeader, QuantizedVertices,
    TileBounds,
};
use rayon::prelude::*;
use std::path::Path;

/// Directory of the tileset in the output directory.
pub const TERRAIN_DIR: &str = "terrain";
/// Largest quantized coordinate.
const QMAX: f64 = 32767.0;
/// gzip level of the tiles: 1 (miniz_oxide's fast greedy path), for speed. autzen_full's
/// tileset holds 79 MB of tiles: written at level 1 they take 27.7 MB; zlib's level 6 (its
/// default) would take 21.5 MB, at about twice zlib's level-1 time (0.83 against 0.39 CPU-s,
/// measured with Python's zlib on the same tiles).
const GZIP_LEVEL: u32 = 1;

/// The vertices' heights quantized between the tile's min and max, and those two.
fn quantize_heights(h: &[f64]) -> (Vec<u16>, f32, f32) {
    let lo = h.iter().copied().fold(f64::INFINITY, f64::min) as f32;
    let hi = h.iter().copied().fold(f64::NEG_INFINITY, f64::max) as f32;
    let span = f64::from(hi) - f64::from(lo);
    let q = h
        .iter()
        .map(|&v| {
            if span > 0.0 {
                ((v - f64::from(lo)) / span * QMAX).round().clamp(0.0, QMAX) as u16
            } else {
                0
            }
        })
        .collect();
    (q, lo, hi)
}

/// Edge lists in Cesium's orders: west south→north, south east→west, east north→south,
/// north west→east.
fn edges(uv: &[[u16; 2]]) -> EdgeIndices {
    let n = Q;
    let pick = |on: &dyn Fn([u16; 2]) -> bool, key: &dyn Fn([u16; 2]) -> i32| {
        let mut v: Vec<(i32, u32)> = uv
            .iter()
            .enumerate()
            .filter(|(_, &p)| on(p))
            .map(|(k, &p)| (key(p), k as u32))
            .collect();
        v.sort_unstable();
        v.into_iter().map(|(_, k)| k).collect()
    };
    EdgeIndices {
        west: pick(&|p| p[0] == 0, &|p| i32::from(p[1])),
        south: pick(&|p| p[1] == 0, &|p| -i32::from(p[0])),
        east: pick(&|p| p[0] == n, &|p| -i32::from(p[1])),
        north: pick(&|p| p[1] == n, &|p| i32::from(p[0])),
    }
}

/// The tile's quantized-mesh-1.0 bytes, gzip-compressed.
pub fn encode_tile(t: &TerrainTile) -> Vec<u8> {
    let (height, lo, hi) = quantize_heights(&t.heights);
    let vertices = QuantizedVertices {
        u: t.uv.iter().map(|p| p[0]).collect(),
        v: t.uv.iter().map(|p| p[1]).collect(),
        height,
    };
    let [w, s, e, n] = t.bounds;
    let lonlat = |k: usize| {
        let [i, j] = t.uv[k].map(|c| f64::from(c) / QMAX);
        [w + (e - w) * i, s + (n - s) * j]
    };
    let bounds = TileBounds::new(w, s, e, n);
    let mut header = QuantizedMeshHeader::from_bounds_with_vertices_iter(
        &bounds,
        lo,
        hi,
        (0..t.uv.len()).map(|k| {
            let [lon, lat] = lonlat(k);
            [lon, lat, t.heights[k]]
        }),
    );
    // The crate's sphere holds the tile's corners and edge midpoints at min/max height; grow
    // it to hold every vertex as well (a tile's inside can bulge past them on coarse levels).
    let c = header.bounding_sphere_center;
    for k in 0..t.uv.len() {
        let [lon, lat] = lonlat(k);
        let p = geodetic_to_ecef(lon, lat, t.heights[k]);
        let d = ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt();
        header.bounding_sphere_radius = header.bounding_sphere_radius.max(d);
    }
    let indices = t.triangles.iter().flatten().copied().collect();
    let edge_indices = edges(&t.uv);
    QuantizedMeshEncoder::new(header, vertices, indices, edge_indices).encode_with_options(
        &EncodeOptions {
            include_normals: true,
            normals: Some(t.normals.clone()),
            compression_level: GZIP_LEVEL,
            ..Default::default()
        },
    )
}

/// `layer.json`: the TileJSON Cesium's `CesiumTerrainProvider` reads.
pub fn layer_json(ts: &Tileset) -> serde_json::Value {
    let available: Vec<serde_json::Value> = ts
        .levels
        .iter()
        .map(|level| {
            level
                .iter()
                .map(|r| {
                    serde_json::json!({
                        "startX": r.x[0], "startY": r.y[0], "endX": r.x[1], "endY": r.y[1]
                    })
                })
                .collect()
        })
        .collect();
    serde_json::json!({
        "tilejson": "2.1.0",
        "name": "terratile",
        "description": format!(
            "quantized-mesh tiles; heights in metres of the input's vertical datum; \
             coarser levels within {0} m of their lattice's resampled heights, the most \
             detailed level an adaptive triangulation within {0} m of the grid's bilinear \
             heights",
            ts.tolerance_m
        ),
        "version": "1.0.0",
        "format": "quantized-mesh-1.0",
        "scheme": "tms",
        "projection": "EPSG:4326",
        "tiles": ["{z}/{x}/{y}.terrain?v={version}"],
        "extensions": ["octvertexnormals"],
        "bounds": ts.bounds,
        "minzoom": 0,
        "maxzoom": ts.levels.len().saturating_sub(1),
        "available": available,
        "attribution": "",
    })
}

/// Writes the tileset under `dir/terrain`; returns the files written, relative to `dir`.
pub fn write(dir: &Path, ts: &Tileset) -> Result<Vec<String>> {
    let root = dir.join(TERRAIN_DIR);
    for r in ts.levels.iter().flatten() {
        for x in r.x[0]..=r.x[1] {
            let p = root.join(format!("{}/{x}", r.z));
            std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        }
    }
    let mut files: Vec<String> = ts
        .tiles
        .par_iter()
        .map(|t| {
            let [z, x, y] = t.zxy;
            let rel = format!("{TERRAIN_DIR}/{z}/{x}/{y}.terrain");
            let p = dir.join(&rel);
            std::fs::write(&p, encode_tile(t)).map_err(|e| Error::io(&p, e))?;
            Ok(rel)
        })
        .collect::<Result<_>>()?;
    let text = serde_json::to_string_pretty(&layer_json(ts))
        .map_err(|e| Error::Internal(e.to_string()))?;
    let p = root.join("layer.json");
    std::fs::write(&p, format!("{text}\n")).map_err(|e| Error::io(&p, e))?;
    files.push(layer_path());
    Ok(files)
}

/// `terrain/layer.json`, relative to the output directory.
pub fn layer_path() -> String {
    format!("{TERRAIN_DIR}/layer.json")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lattice_quantizes_to_the_edges() {
        use crate::geo::tms::lattice_uv;
        assert_eq!(lattice_uv(0), 0);
        assert_eq!(lattice_uv(64), 32767);
        assert_eq!(lattice_uv(32), 16384);
    }

    #[test]
    fn edge_orders_are_cesiums() {
        let uv = [[0, 0], [Q, 0], [Q, Q], [0, Q], [0, 9], [5, 0]];
        let e = edges(&uv);
        assert_eq!(e.west, vec![0, 4, 3]);
        assert_eq!(e.south, vec![1, 5, 0]);
        assert_eq!(e.east, vec![2, 1]);
        assert_eq!(e.north, vec![3, 2]);
    }
}
