//! The tile outputs on real data: every EXR read back with the `exr` crate equals the tiles,
//! the manifest alone puts the heightfield back together exactly, the 16-bit heightmaps
//! decode within half a step, the .glb meshes load, and the outputs are byte-identical for
//! any thread count.

mod common;
mod tiles_support;

use exr::prelude::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;
use terratile::mesh::io::MeshFormat;
use terratile::output::{write_terrain, OutputConfig, TerrainProducts};
use terratile::terrain::extract::{extract_meshes, ExtractParams};
use terratile::terrain::quadtree::{build, QuadtreeParams};
use terratile::terrain::tiles::{tile, Preset, TileParams, TileSet};
use terratile::terrain::Heightfield;
use terratile::NoProgress;
use tiles_support::*;

/// Tiles of `size` samples, no preset.
fn sized(size: usize) -> TileParams {
    TileParams {
        size: Some(size),
        ..Default::default()
    }
}

/// What [`write_all`] wrote: the files and the tile meshes' surface triangles.
struct Written {
    files: Vec<String>,
    triangles: usize,
}

/// Tiles, quadtree, meshes (when `out` wants them) and every output, as the pipeline runs
/// them.
fn write_all(
    hf: &Heightfield,
    params: &TileParams,
    out: &OutputConfig,
    dir: &Path,
) -> (TileSet, Written) {
    let set = tile(hf, params).unwrap();
    let qt = build(&set, &QuadtreeParams::default()).unwrap();
    let meshes = out
        .wants_meshes()
        .then(|| extract_meshes(&set, &qt, &ExtractParams::default()).unwrap());
    let products = TerrainProducts {
        set: &set,
        quadtree: &qt,
        meshes: meshes.as_ref(),
    };
    let files = write_terrain(dir, &products, out, &NoProgress).unwrap();
    let triangles = meshes.map_or(0, |m| m.triangles);
    (set, Written { files, triangles })
}

/// Reads an EXR channel with the exr crate, as rows south first.
fn exr_channels(path: &Path) -> (usize, BTreeMap<String, Vec<f32>>) {
    let image = read_first_flat_layer_from_file(path).unwrap();
    let layer = image.layer_data;
    let w = layer.size.width();
    let mut out = BTreeMap::new();
    for ch in &layer.channel_data.list {
        let v: Vec<f32> = ch.sample_data.values_as_f32().collect();
        let south_first: Vec<f32> = v.chunks(w).rev().flatten().copied().collect();
        out.insert(ch.name.to_string(), south_first);
    }
    (w, out)
}

/// Puts the whole heightfield back together from the manifest and the EXR files alone.
fn reassemble(dir: &Path) -> (Vec<f32>, usize, usize, f64) {
    let m: Value =
        serde_json::from_slice(&std::fs::read(dir.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["tiling"]["exr_row_order"], "north-first");
    let cols = m["grid"]["samples"][0].as_u64().unwrap() as usize;
    let rows = m["grid"]["samples"][1].as_u64().unwrap() as usize;
    let mut g = vec![f32::INFINITY; cols * rows];
    for t in m["tiles"].as_array().unwrap() {
        let (ox, oy) = (
            t["grid_offset"][0].as_u64().unwrap() as usize,
            t["grid_offset"][1].as_u64().unwrap() as usize,
        );
        let (vw, vh) = (
            t["valid"][0].as_u64().unwrap() as usize,
            t["valid"][1].as_u64().unwrap() as usize,
        );
        let (w, ch) = exr_channels(&dir.join(t["files"]["exr"].as_str().unwrap()));
        // The file says north-first; exr_channels turned it south-first.
        let h = &ch["height"];
        for j in 0..vh {
            for i in 0..vw {
                g[(oy + j) * cols + ox + i] = h[j * w + i];
            }
        }
    }
    (g, cols, rows, m["grid"]["z_offset"].as_f64().unwrap())
}

#[test]
fn real_tiles_round_trip_through_every_output() {
    let Some(path) = common::data_file("lidar/autzen_trim.las") else {
        return;
    };
    let hf = heightfield_from_points(&read_points(&path), true);
    let dir = tempfile::tempdir().unwrap();
    let out = OutputConfig {
        preview_size: 600,
        meshes: vec![MeshFormat::PlyBinaryLe, MeshFormat::Obj, MeshFormat::Glb],
        ..Default::default()
    };
    let (set, w) = write_all(&hf, &sized(65), &out, dir.path());
    let qt = build(&set, &QuadtreeParams::default()).unwrap();
    assert!(w.triangles > 0);
    // Every EXR: every sample of height and d2 equal, no mask (no holes).
    for (t, tl) in set.tiles.iter().enumerate() {
        let name = format!("tiles/tile_{:03}_{:03}.exr", tl.col, tl.row);
        let (n, ch) = exr_channels(&dir.path().join(&name));
        assert_eq!(n, 65);
        assert!(!ch.contains_key("mask"));
        for (a, b) in ch["height"].iter().zip(tl.heights.iter()) {
            assert_eq!(a.to_bits(), b.to_bits(), "{name}");
        }
        for (a, b) in ch["d2"].iter().zip(qt.d2[t].to_matrix().iter()) {
            assert_eq!(a.to_bits(), b.to_bits(), "{name}");
        }
    }
    // The manifest alone reassembles the heightfield exactly.
    let (g, cols, rows, z_offset) = reassemble(dir.path());
    assert_eq!((cols, rows), (hf.cols(), hf.rows()));
    assert_eq!(z_offset, hf.z_offset);
    for (a, b) in g.iter().zip(hf.heights.iter()) {
        assert_eq!(a.to_bits(), b.to_bits());
    }
    // Heightmaps decode within half a step; PNG is north-up, RAW south first.
    let m: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap()).unwrap();
    let (scale, offset) = (
        m["heightmaps"]["z_scale"].as_f64().unwrap(),
        m["heightmaps"]["z_offset"].as_f64().unwrap(),
    );
    assert_eq!(m["crs"]["metres_per_unit"], 0.3048);
    for tl in &set.tiles {
        let stem = format!("heightmaps/tile_{:03}_{:03}", tl.col, tl.row);
        let png = image::open(dir.path().join(format!("{stem}.png")))
            .unwrap()
            .into_luma16();
        let raw = std::fs::read(dir.path().join(format!("{stem}.raw"))).unwrap();
        assert_eq!(raw.len(), 65 * 65 * 2);
        for j in 0..65 {
            for i in 0..65 {
                let v = u16::from_le_bytes([raw[(j * 65 + i) * 2], raw[(j * 65 + i) * 2 + 1]]);
                assert_eq!(png.get_pixel(i as u32, (64 - j) as u32).0[0], v);
                let z = offset + v as f64 * scale;
                let truth = hf.z_offset + tl.heights[[j, i]] as f64;
                assert!(
                    (z - truth).abs() <= scale / 2.0 + 1e-9,
                    "{stem} ({i},{j}): {z} vs {truth}"
                );
            }
        }
    }
    // Meshes load through the gltf crate, with normals.
    let glb = std::fs::read(dir.path().join("meshes/tile_000_000.glb")).unwrap();
    let g = gltf::Gltf::from_slice(&glb).unwrap();
    let prim = g.meshes().next().unwrap().primitives().next().unwrap();
    let reader = prim.reader(|_| g.blob.as_deref());
    assert!(reader
        .read_normals()
        .unwrap()
        .all(|n| (n[0] * n[0] + n[1] * n[1] + n[2] * n[2] - 1.0).abs() < 1e-4));
    let tri_count = reader.read_indices().unwrap().into_u32().count() / 3;
    assert_eq!(Some(tri_count as u64), m["tiles"][0]["triangles"].as_u64());
    // PLY and OBJ read back through the mesh module: same triangles, positions (z up, CRS
    // units: feet here) as the glb (y up, metres).
    let glb_pos: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
    for ext in ["ply", "obj"] {
        let mesh =
            terratile::mesh::io::read(&dir.path().join(format!("meshes/tile_000_000.{ext}")))
                .unwrap();
        assert_eq!(mesh.triangle_count(), tri_count, "{ext}");
        assert!(mesh.normals.is_some(), "{ext}");
        assert_eq!(mesh.vertex_count(), glb_pos.len(), "{ext}");
        let ft = 0.3048f32;
        for (p, g) in mesh.positions.iter().zip(&glb_pos) {
            assert_eq!([p.x * ft, p.z * ft, -p.y * ft], *g, "{ext}");
        }
    }
    // Previews.
    let relief = image::open(dir.path().join("preview/relief.png")).unwrap();
    assert_eq!(relief.width().max(relief.height()), 600);
    // North up, the terrain's proportions kept (autzen_trim's cells are not square).
    let (ew, eh) = (
        hf.cols() as f64 * hf.cell_size[0],
        hf.rows() as f64 * hf.cell_size[1],
    );
    let aspect = relief.width() as f64 / relief.height() as f64;
    assert!(
        (aspect / (ew / eh) - 1.0).abs() < 0.01,
        "{aspect} vs {}",
        ew / eh
    );
    assert!(dir.path().join("preview/wireframe.png").is_file());
    // The file list is what is on disk.
    let on_disk: Vec<String> = common::walk(dir.path())
        .into_iter()
        .filter(|p| p.is_file())
        .map(|p| {
            p.strip_prefix(dir.path())
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/")
        })
        .collect();
    let mut on_disk = on_disk;
    on_disk.sort();
    assert_eq!(on_disk, w.files);
}

#[test]
fn holes_are_masked_and_kept_through_reassembly() {
    let Some(path) = common::data_file("lidar/Topography.laz") else {
        return;
    };
    let hf = heightfield_from_points(&read_points(&path), false);
    let holes = hf.heights.iter().filter(|h| h.is_nan()).count();
    assert!(holes > 0);
    let dir = tempfile::tempdir().unwrap();
    let out = OutputConfig {
        meshes: vec![],
        wireframe: false,
        preview_size: 300,
        ..Default::default()
    };
    let (set, _) = write_all(&hf, &sized(129), &out, dir.path());
    let (g, _, _, _) = reassemble(dir.path());
    for (a, b) in g.iter().zip(hf.heights.iter()) {
        assert_eq!(a.to_bits(), b.to_bits());
    }
    let m: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["grid"]["holes"].as_u64().unwrap() as usize, holes);
    assert_eq!(m["heightmaps"]["nodata"], 0);
    let (_, ch) = exr_channels(&dir.path().join("tiles/tile_000_000.exr"));
    let mask = &ch["mask"];
    for (k, h) in ch["height"].iter().enumerate() {
        assert_eq!(mask[k] == 0.0, h.is_nan());
    }
    assert!(m["meshes"].is_null());
    // Asking for meshes now is an error.
    let qt = build(&set, &QuadtreeParams::default()).unwrap();
    let e = extract_meshes(&set, &qt, &ExtractParams::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("masked hole samples; meshes need a filled heightfield"),
        "{e}"
    );
}

#[test]
fn outputs_are_byte_identical_for_any_thread_count() {
    let hf = synthetic(300, 200, 9, 1.0);
    let mut seen: Option<BTreeMap<String, Vec<u8>>> = None;
    for threads in [1, 2, 8] {
        let dir = tempfile::tempdir().unwrap();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let out = OutputConfig {
            preview_size: 400,
            ..Default::default()
        };
        let w = pool.install(|| write_all(&hf, &sized(65), &out, dir.path()).1);
        let files: BTreeMap<String, Vec<u8>> = w
            .files
            .iter()
            .map(|f| (f.clone(), std::fs::read(dir.path().join(f)).unwrap()))
            .collect();
        if let Some(prev) = &seen {
            assert_eq!(
                prev.keys().collect::<Vec<_>>(),
                files.keys().collect::<Vec<_>>()
            );
            for (k, v) in &files {
                assert!(prev[k] == *v, "{k} differs with {threads} threads");
            }
        }
        seen = Some(files);
    }
}

#[test]
fn presets_describe_the_engines() {
    let hf = synthetic(600, 300, 3, 0.5);
    let dir = tempfile::tempdir().unwrap();
    let out = OutputConfig {
        meshes: vec![],
        wireframe: false,
        relief: false,
        ..Default::default()
    };
    let (set, _) = write_all(
        &hf,
        &TileParams {
            size: None,
            preset: Preset::Unity,
        },
        &out,
        dir.path(),
    );
    assert_eq!(set.tile_size, 513);
    let m: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["unity"]["heightmap_resolution"], 513);
    assert!(m["unreal"].is_null());

    let dir = tempfile::tempdir().unwrap();
    let (set, _) = write_all(
        &hf,
        &TileParams {
            size: Some(257),
            preset: Preset::Unreal,
        },
        &out,
        dir.path(),
    );
    assert_eq!(set.samples, [1009, 505]);
    let m: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["unreal"]["resolution"][0], 1009);
    let png = image::open(dir.path().join("heightmaps/landscape.png")).unwrap();
    assert_eq!((png.width(), png.height()), (1009, 505));
    assert_eq!(
        std::fs::metadata(dir.path().join("heightmaps/landscape.r16"))
            .unwrap()
            .len(),
        1009 * 505 * 2
    );
    // Unreal's z: location + (v − 32768) · scale / 128 cm = world z.
    let (s, o) = (
        m["heightmaps"]["z_scale"].as_f64().unwrap(),
        m["heightmaps"]["z_offset"].as_f64().unwrap(),
    );
    let (sz, lz) = (
        m["unreal"]["scale_cm"][2].as_f64().unwrap(),
        m["unreal"]["location_z_cm"].as_f64().unwrap(),
    );
    for v in [0u16, 1000, 65535] {
        let world_cm = (o + v as f64 * s) * 100.0;
        assert!((lz + (v as f64 - 32768.0) * sz / 128.0 - world_cm).abs() < 1e-6);
    }
}
