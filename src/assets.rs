//! The `[[assets]]` stage: model meshes (buildings, rocks, props) simplified by vertex
//! clustering (Kim et al. 1999), scored by the Metro-style error (Cignoni et al. 1998) and placed on the
//! terrain: turned to z-up, scaled, rotated about the vertical, centred on (x, y) and set
//! down with their lowest point on the terrain height there (bilinear in the run's
//! heightfield).
//!
//! ```toml
//! [[assets]]
//! input = "models/rock.obj"          # relative to the pipeline file
//! output = "assets/rock.ply"         # relative to the output directory; .obj or .ply
//! simplify = { method = "octree", ratio = 0.25 }
//! place = { x = 512.0, y = 300.0, rotation = 30.0 }
//! ```
//!
//! Output coordinates are local: world minus `origin` (the heightfield's south-west corner
//! and z offset), because f32 vertex positions cannot hold projected world coordinates
//! (hundreds of kilometres) to the centimetre. The run summary gives the origin.

use crate::error::{Error, Result};
use crate::mesh::{self, HausdorffParams, HausdorffReport, TriMesh};
use crate::simplify::{self, Method, SimplifyParams};
use crate::terrain::heightfield::Heightfield;
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One `[[assets]]` entry.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct AssetConfig {
    /// The model (OBJ or PLY), relative to the pipeline file's directory.
    pub input: PathBuf,
    /// The placed mesh to write (`.obj`, or `.ply` for binary PLY), relative to the output
    /// directory.
    pub output: PathBuf,
    /// How to simplify it: `method` and one target (`ratio`, `triangles`, `cell_size` or
    /// `threshold`), as for `terratile simplify`. Absent: the mesh is placed as it is.
    #[serde(default)]
    pub simplify: Option<SimplifyParams>,
    /// Also write the placed mesh as progressive triangle strips (a `.tps` stream, and one
    /// level as a glTF `TRIANGLE_STRIP` if asked). Absent: no strips.
    #[serde(default)]
    pub strips: Option<crate::simplify::strips::asset::AssetStrips>,
    /// Where it goes on the terrain.
    pub place: Placement,
    /// Refuse a model that is read with a warning by default (unusable texture coordinates,
    /// normals or colours; faces with fewer than 3 vertices), like `--strict`.
    #[serde(default)]
    pub strict: bool,
}

/// Which model axis points up.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    /// +y is up (the OBJ/PLY convention of most modelling tools and scans): turned to z-up.
    #[default]
    Y,
    /// +z is up, like the terrain.
    Z,
}

/// Placement of an asset on the terrain.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Placement {
    /// World x (east) of the asset's footprint centre.
    pub x: f64,
    /// World y (north) of the asset's footprint centre.
    pub y: f64,
    /// Turn about the vertical, degrees counter-clockwise seen from above (default 0).
    #[serde(default)]
    pub rotation: f64,
    /// Uniform scale from model units to world units (default 1).
    #[serde(default = "one")]
    pub scale: f64,
    /// The model's up axis, `y` (default) or `z`.
    #[serde(default)]
    pub up: UpAxis,
    /// Height of the asset's lowest point above the terrain (default 0; negative sinks it).
    #[serde(default)]
    pub z_offset: f64,
}

fn one() -> f64 {
    1.0
}

/// What the stage did with one asset (listed in the run summary).
#[derive(Debug, Clone, Serialize)]
pub struct AssetReport {
    /// The input model.
    pub input: PathBuf,
    /// The written file, relative to the output directory.
    pub output: PathBuf,
    /// Clustering method, when simplified.
    pub method: Option<Method>,
    /// Triangles read.
    pub triangles_in: usize,
    /// Triangles written.
    pub triangles_out: usize,
    /// Error of the simplified model against the model (model units and % of its diagonal;
    /// multiply by `scale` for world units). None when not simplified.
    pub error: Option<HausdorffReport>,
    /// World position of the footprint centre at ground level (x, y, terrain z).
    pub position: [f64; 3],
    /// True when the ground height came from the heightfield, false when there was none
    /// and the base was set at z = 0.
    pub on_terrain: bool,
    /// Seconds for the whole asset (read, simplify, measure, write).
    pub seconds: f64,
    /// What the reader noticed in the model (dropped attributes, skipped faces).
    pub warnings: Vec<String>,
    /// The progressive strips written, when `strips` is set.
    pub strips: Option<crate::simplify::strips::format::BuildReport>,
}

impl Placement {
    /// Checks the values; `key` names the table in messages (e.g. `assets[0].place`).
    pub fn validate(&self, key: &str) -> Result<()> {
        for (name, v) in [
            ("x", self.x),
            ("y", self.y),
            ("rotation", self.rotation),
            ("z_offset", self.z_offset),
        ] {
            if !v.is_finite() {
                return Err(Error::key(
                    format!("{key}.{name}"),
                    format!("{v} is not a finite number"),
                ));
            }
        }
        if !(self.scale.is_finite() && self.scale > 0.0) {
            return Err(Error::key(
                format!("{key}.scale"),
                format!("{} must be a positive number", self.scale),
            ));
        }
        Ok(())
    }
}

/// `mesh` in world coordinates minus `origin`: turned z-up, scaled, rotated, its footprint
/// centred on (x, y) and its lowest point at `ground + z_offset`. Normals turn with it.
pub fn place(mesh: &TriMesh, p: &Placement, ground: f64, origin: [f64; 3]) -> TriMesh {
    let (s, c) = p.rotation.to_radians().sin_cos();
    let up = |v: DVec3| match p.up {
        UpAxis::Y => DVec3::new(v.x, -v.z, v.y),
        UpAxis::Z => v,
    };
    let turn = |v: DVec3| DVec3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z);
    let local: Vec<DVec3> = mesh
        .positions
        .iter()
        .map(|q| turn(up(q.as_dvec3()) * p.scale))
        .collect();
    let used = mesh.referenced();
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for (q, u) in local.iter().zip(&used) {
        if *u {
            lo = lo.min(*q);
            hi = hi.max(*q);
        }
    }
    let shift = DVec3::new(
        p.x - 0.5 * (lo.x + hi.x) - origin[0],
        p.y - 0.5 * (lo.y + hi.y) - origin[1],
        ground + p.z_offset - lo.z - origin[2],
    );
    let mut out = mesh.clone();
    out.positions = local.iter().map(|q| (*q + shift).as_vec3()).collect();
    if let Some(n) = out.normals.as_mut() {
        for v in n.iter_mut() {
            *v = turn(up(v.as_dvec3())).as_vec3();
        }
    }
    out
}

/// Runs one asset: read, simplify, measure, place, write `out_dir/output`. `key` names the
/// entry in messages (`assets[2]`).
pub fn run_asset(
    cfg: &AssetConfig,
    base_dir: &Path,
    out_dir: &Path,
    heightfield: Option<&Heightfield>,
    origin: [f64; 3],
) -> Result<AssetReport> {
    let t = Instant::now();
    let input = base_dir.join(&cfg.input);
    let read = mesh::io::ReadOptions { strict: cfg.strict };
    let (model, warnings) = mesh::io::read_surface_with(&input, &read)?;
    let (result, method, error) = match &cfg.simplify {
        Some(params) => {
            let s = simplify::simplify(&model, params)?;
            let e = mesh::hausdorff(&model, &s.mesh, &HausdorffParams::default())?;
            (s.mesh, Some(params.method), Some(e))
        }
        None => (model.clone(), None, None),
    };
    let p = &cfg.place;
    let ground = match heightfield {
        Some(hf) => hf.sample_bilinear(p.x, p.y).ok_or_else(|| Error::Data {
            stage: "assets",
            message: format!(
                "{}: ({}, {}) is outside the terrain or over a hole in it",
                cfg.input.display(),
                p.x,
                p.y
            ),
        })?,
        None => 0.0,
    };
    let placed = place(&result, p, ground, origin);
    let out = out_dir.join(&cfg.output);
    if let Some(parent) = out.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    mesh::io::write(&placed, &out)?;
    let strips = match &cfg.strips {
        Some(s) => Some(s.write(&placed, &cfg.input, out_dir)?),
        None => None,
    };
    Ok(AssetReport {
        input: cfg.input.clone(),
        output: cfg.output.clone(),
        method,
        triangles_in: model.triangle_count(),
        triangles_out: placed.triangle_count(),
        error,
        position: [p.x, p.y, ground],
        on_terrain: heightfield.is_some(),
        seconds: t.elapsed().as_secs_f64(),
        warnings,
        strips,
    })
}

/// Checks every entry before any work: placement values, simplification targets, output
/// formats, input files present. Errors are [`Error::Key`]s, for the pipeline file's loader to
/// locate.
pub fn validate(assets: &[AssetConfig], base_dir: &Path) -> Result<()> {
    for (i, a) in assets.iter().enumerate() {
        let key = format!("assets[{i}]");
        a.place.validate(&format!("{key}.place"))?;
        if let Some(s) = &a.simplify {
            if let Err(e) = s.target(1) {
                return Err(match e {
                    Error::Param {
                        param,
                        value,
                        message,
                        ..
                    } => Error::key(
                        format!(
                            "{key}.simplify.{}",
                            param.split('.').next().unwrap_or(param)
                        ),
                        format!("{value}: {message}"),
                    ),
                    other => Error::key(format!("{key}.simplify"), other.to_string()),
                });
            }
        }
        if let Err(e) = mesh::io::MeshFormat::for_output(&a.output) {
            return Err(Error::key(format!("{key}.output"), e.to_string()));
        }
        let input = base_dir.join(&a.input);
        if !input.is_file() {
            return Err(Error::key(
                format!("{key}.input"),
                format!("{} does not exist", input.display()),
            ));
        }
        if !inside(&a.output) {
            return Err(Error::key(
                format!("{key}.output"),
                "must be a relative path inside the output directory",
            ));
        }
        if let Some(s) = &a.strips {
            s.validate(&format!("{key}.strips"), inside)?;
        }
    }
    Ok(())
}

/// Whether `path` is relative and stays inside the directory it is joined to.
fn inside(path: &Path) -> bool {
    !path.is_absolute()
        && !path
            .components()
            .any(|c| matches!(c, std::path::Component::ParentDir))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn cube() -> TriMesh {
        let mut m = TriMesh::default();
        for i in 0..8 {
            m.positions.push(Vec3::new(
                (i & 1) as f32,
                ((i >> 1) & 1) as f32 * 2.0,
                ((i >> 2) & 1) as f32 * 3.0,
            ));
        }
        m.indices = vec![[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5]];
        m
    }

    #[test]
    fn placement_centres_turns_and_grounds() {
        let p = Placement {
            x: 100.0,
            y: 50.0,
            rotation: 90.0,
            scale: 2.0,
            up: UpAxis::Z,
            z_offset: 0.5,
        };
        let out = place(&cube(), &p, 10.0, [90.0, 40.0, 0.0]);
        let b = out.bounds().unwrap();
        // 90° turns the 1 × 2 footprint (scaled to 2 × 4) into 4 × 2, centred on (10, 10).
        assert!(
            (b.min.x - 8.0).abs() < 1e-5 && (b.max.x - 12.0).abs() < 1e-5,
            "{b:?}"
        );
        assert!(
            (b.min.y - 9.0).abs() < 1e-5 && (b.max.y - 11.0).abs() < 1e-5,
            "{b:?}"
        );
        assert!(
            (b.min.z - 10.5).abs() < 1e-5 && (b.max.z - 16.5).abs() < 1e-5,
            "{b:?}"
        );
    }

    #[test]
    fn y_up_models_stand_up() {
        let p = Placement {
            x: 0.0,
            y: 0.0,
            rotation: 0.0,
            scale: 1.0,
            up: UpAxis::Y,
            z_offset: 0.0,
        };
        let out = place(&cube(), &p, 0.0, [0.0; 3]);
        let b = out.bounds().unwrap();
        // The model's y extent (2) becomes the height.
        assert!((b.max.z - b.min.z - 2.0).abs() < 1e-6, "{b:?}");
    }

    #[test]
    fn ground_comes_from_the_heightfield() {
        let dir = tempfile::tempdir().unwrap();
        mesh::io::write(&cube(), &dir.path().join("c.obj")).unwrap();
        let hf = crate::terrain::testutil::field(4, 4, |i, j| (i + 10 * j) as f32);
        let cfg = AssetConfig {
            input: "c.obj".into(),
            output: "out/c.ply".into(),
            simplify: None,
            strips: None,
            place: Placement {
                x: 2.0,
                y: 1.5,
                rotation: 0.0,
                scale: 1.0,
                up: UpAxis::Z,
                z_offset: 0.0,
            },
            strict: false,
        };
        let r = run_asset(&cfg, dir.path(), dir.path(), Some(&hf), [0.0; 3]).unwrap();
        // Bilinear between centres (1.5, 0.5)…(2.5, 1.5): 1.5 + 10·1.0 = 11.5.
        assert!((r.position[2] - 11.5).abs() < 1e-9, "{r:?}");
        let m = mesh::io::read(&dir.path().join("out/c.ply")).unwrap();
        assert!((m.bounds().unwrap().min.z - 11.5).abs() < 1e-5);
        let far = AssetConfig {
            place: Placement {
                x: 99.0,
                ..cfg.place
            },
            ..cfg
        };
        let e = run_asset(&far, dir.path(), dir.path(), Some(&hf), [0.0; 3]).unwrap_err();
        assert!(e.to_string().contains("outside the terrain"), "{e}");
    }
}
