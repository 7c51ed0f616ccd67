//! Saliency for the quadric simplifier (An's thesis, "Mesh simplification with hybrid
//! saliency"): what the shape says ([`mesh`]: curvature and Lee et al.'s mesh saliency).
//! The per-vertex maps become the weight H of [`crate::simplify::qem::QemParams::weights`].

pub(crate) mod grid;
pub mod hybrid;
pub mod image;
pub mod itti;
pub mod mesh;
pub mod phases;
pub mod render;
pub mod texture;

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use serde::{Deserialize, Serialize};

/// Which saliency weights the quadric simplifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Saliency {
    /// Plain QEM.
    #[default]
    None,
    /// Lee et al.'s mesh saliency.
    Mesh,
    /// The mean multi-view image saliency.
    Image,
    /// An's hybrid saliency.
    Hybrid,
}

impl std::fmt::Display for Saliency {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Saliency::None => "none",
            Saliency::Mesh => "mesh",
            Saliency::Image => "image",
            Saliency::Hybrid => "hybrid",
        })
    }
}

/// The default lower end of the weights H ∈ [h_min, 1]: the least salient vertex's planes
/// count a fiftieth of the most salient one's (with the two phases, [`phases`]; one
/// weighted run was best at 0.05, README).
pub const H_MIN: f64 = 0.02;

/// Refuses h_min outside (0, 1].
pub fn check_h_min(h_min: f64) -> Result<()> {
    if h_min > 0.0 && h_min <= 1.0 {
        Ok(())
    } else {
        Err(Error::param(
            "simplify",
            "saliency_h_min",
            h_min,
            "must be in (0, 1]",
        ))
    }
}

/// Every per-vertex map, in the input's vertex order.
#[derive(Debug, Clone, PartialEq)]
pub struct Maps {
    /// |mean curvature| (1 / model units).
    pub curvature: Vec<f64>,
    /// Lee et al.'s mesh saliency.
    pub mesh_saliency: Vec<f64>,
    /// Image saliency over the views: max, min, mean (each in [0, 1]).
    pub image: image::ImageSaliency,
    /// The hybrid saliency in [0, 1] (the thesis' classes, raw: the weighting smooths it).
    pub hybrid: Vec<f64>,
    /// The hybrid class of each vertex (0–4 for A–E).
    pub class: Vec<u8>,
}

/// All maps of `mesh` (which must be valid and have triangles).
pub fn maps(mesh: &TriMesh, views: &image::ViewParams) -> Result<Maps> {
    let m = mesh::mesh_saliency(mesh);
    Ok(assemble(mesh, m, image::image_saliency(mesh, views)?))
}

/// The maps with the hybrid (the thesis' classes, [`hybrid::hybrid`], class A on
/// [`hybrid::class_curvature`]) of `m` and `image` on `mesh`.
fn assemble(mesh: &TriMesh, m: mesh::MeshSaliency, image: image::ImageSaliency) -> Maps {
    let curvature = hybrid::class_curvature(mesh, &m.curvature, hybrid::CURVATURE_SMOOTH);
    let (hybrid, class) =
        hybrid::hybrid(&curvature, &m.saliency, &image.max, &image.min, &image.mean);
    Maps {
        curvature: m.curvature,
        mesh_saliency: m.saliency,
        image,
        hybrid,
        class,
    }
}

/// How a saliency map becomes the simplifier's weights H: the same for every map (mesh,
/// image or hybrid saliency).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Weighting {
    /// The least weight, in (0, 1] ([`H_MIN`]).
    pub h_min: f64,
    /// σ of the Gaussian smoothing in ε (0.3 % of the diagonal); 0: none
    /// ([`hybrid::SMOOTH`]).
    pub smooth: f64,
    /// Whether each vertex then takes the value of the most salient triangle around it
    /// ([`mesh::face_max`]).
    pub spread: bool,
    /// The shape of H over the ranks ([`hybrid::weights`]; 1: geometric).
    pub power: f64,
    /// Whether the ranks count surface area (each vertex a third of its triangles' area)
    /// rather than vertices ([`hybrid::area_ranks`]).
    pub area_rank: bool,
    /// The top share of the ranks that all get H = 1 (0: none; [`hybrid::weights_of_ranks`]).
    pub plateau: f64,
    /// The salient share of the area: ranks at or above 1 − `top` get H = 1 and the rest at
    /// most `gap` ([`hybrid::step_weights`]; 0: the curve of `power` and `plateau`).
    pub top: f64,
    /// With `top`: the weight just below the salient share (h_min at the bottom, geometric
    /// in the rank between; `gap` = h_min: every unsalient vertex at h_min).
    pub gap: f64,
    /// The two-phase order ([`phases`]): the unsalient surface's share of the target after
    /// phase 1 (0: one weighted run).
    pub phases: f64,
}

impl Default for Weighting {
    fn default() -> Self {
        Weighting {
            h_min: H_MIN,
            smooth: hybrid::SMOOTH,
            spread: true,
            power: POWER,
            area_rank: true,
            plateau: 0.0,
            top: 0.0,
            gap: 1.0,
            phases: phases::SHARE,
        }
    }
}

/// The default shape of the weights over the ranks ([`hybrid::weights`]).
pub const POWER: f64 = 1.0;

impl Weighting {
    /// The weights H of `values` on `mesh` ([`weight_values`], ranked, then
    /// [`hybrid::weights_of_ranks`]); `None` (plain QEM) when every value is the same.
    pub fn weights(&self, mesh: &TriMesh, values: &[f64]) -> Option<Vec<f64>> {
        let v = weight_values(mesh, values, self);
        if !hybrid::varies(&v) {
            return None;
        }
        let ranks = if self.area_rank {
            hybrid::area_ranks(&v, &vertex_areas(mesh))
        } else {
            hybrid::ranks(&v)
        };
        if self.top > 0.0 {
            return Some(hybrid::step_weights(&ranks, self.h_min, self.top, self.gap));
        }
        Some(hybrid::weights_of_ranks(
            &ranks,
            self.h_min,
            self.power,
            self.plateau,
        ))
    }
}

impl Weighting {
    /// The weighting's own salient fifth: the vertices whose [`weight_values`] rank in the
    /// top fifth of the area (the share issue 12's evaluation calls salient), which
    /// [`phases`] keeps through phase 1.
    pub fn salient(&self, mesh: &TriMesh, values: &[f64]) -> Vec<bool> {
        let v = weight_values(mesh, values, self);
        hybrid::area_ranks(&v, &vertex_areas(mesh))
            .iter()
            .map(|&u| u >= 1.0 - SALIENT_SHARE)
            .collect()
    }

    /// Simplifies `mesh` as `p` says (its `weights` ignored) with the weights of `values`:
    /// plain QEM when they are the same everywhere, two phases ([`phases`]) when
    /// `self.phases` > 0 and the weights go in the quadrics, else one weighted run.
    pub fn simplify(
        &self,
        mesh: &TriMesh,
        p: &crate::simplify::qem::QemParams,
        values: &[f64],
    ) -> Result<crate::simplify::qem::QemResult> {
        use crate::simplify::qem;
        let Some(h) = self.weights(mesh, values) else {
            let plain = qem::QemParams {
                weights: None,
                ..p.clone()
            };
            return qem::simplify(mesh, &plain);
        };
        if self.phases > 0.0 && p.weight_rule == qem::WeightRule::Quadric {
            return phases::simplify(mesh, p, &h, &self.salient(mesh, values), self.phases);
        }
        let one = qem::QemParams {
            weights: Some(h.into()),
            ..p.clone()
        };
        qem::simplify(mesh, &one)
    }
}

/// The share of the area the weighting treats as salient in [`Weighting::salient`].
pub const SALIENT_SHARE: f64 = 0.2;

/// A third of the area of every triangle at each vertex (welded copies each count their own
/// triangles; they share their value, so the ranks add them up).
fn vertex_areas(mesh: &TriMesh) -> Vec<f64> {
    let mut a = vec![0.0f64; mesh.vertex_count()];
    for (f, t) in mesh.indices.iter().enumerate() {
        let third = mesh.face_area(f) / 3.0;
        for &v in t {
            a[v as usize] += third;
        }
    }
    a
}

/// The per-vertex values the weights are ranked by: `values` smoothed over σ =
/// `w.smooth` · ε, then (with `w.spread`) the most salient triangle around each vertex.
pub fn weight_values(mesh: &TriMesh, values: &[f64], w: &Weighting) -> Vec<f64> {
    let mut v = if w.smooth > 0.0 {
        mesh::smooth(mesh, values, w.smooth)
    } else {
        values.to_vec()
    };
    if w.spread {
        v = mesh::face_max(mesh, &v);
    }
    v
}

/// The per-vertex map of `kind` for `mesh` that the weights are made from (`None` for
/// [`Saliency::None`]).
pub fn values(
    mesh: &TriMesh,
    kind: Saliency,
    views: &image::ViewParams,
) -> Result<Option<Vec<f64>>> {
    Ok(Some(match kind {
        Saliency::None => return Ok(None),
        Saliency::Mesh => mesh::mesh_saliency(mesh).saliency,
        Saliency::Image => image::image_saliency(mesh, views)?.mean,
        Saliency::Hybrid => maps(mesh, views)?.hybrid,
    }))
}

/// The weights H ∈ [h_min, 1] of `kind` for `mesh` (`None`: plain QEM, also when the
/// saliency is the same everywhere).
pub fn weights(
    mesh: &TriMesh,
    kind: Saliency,
    h_min: f64,
    views: &image::ViewParams,
) -> Result<Option<Vec<f64>>> {
    check_h_min(h_min)?;
    let w = Weighting {
        h_min,
        ..Weighting::default()
    };
    Ok(values(mesh, kind, views)?.and_then(|v| w.weights(mesh, &v)))
}
pub mod pictures;

/// What `terratile saliency` computed and wrote.
#[derive(Debug, Clone, Serialize)]
pub struct FileReport {
    /// The input mesh.
    pub input: std::path::PathBuf,
    /// The directory written.
    pub out: std::path::PathBuf,
    /// Vertices and triangles of the input.
    pub vertices: usize,
    /// Triangles.
    pub triangles: usize,
    /// Distinct views rendered.
    pub views: usize,
    /// Seconds for curvature and mesh saliency.
    pub mesh_seconds: f64,
    /// Seconds for the multi-view image saliency.
    pub image_seconds: f64,
    /// Vertices per hybrid class A–E.
    pub classes: [usize; 5],
    /// Per map (in [`pictures::NAMES`] order): min, mean, max.
    pub stats: Vec<(String, [f64; 3])>,
    /// The files written.
    pub files: Vec<std::path::PathBuf>,
}

impl std::fmt::Display for FileReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{}: {} vertices, {} triangles; mesh saliency {:.3} s, image saliency {:.3} s ({} views)",
            self.input.display(),
            self.vertices,
            self.triangles,
            self.mesh_seconds,
            self.image_seconds,
            self.views
        )?;
        let [a, b, c, d, e] = self.classes;
        writeln!(f, "hybrid classes: A {a}, B {b}, C {c}, D {d}, E {e}")?;
        for (n, [lo, mean, hi]) in &self.stats {
            writeln!(f, "{n:>14}: min {lo:.4}, mean {mean:.4}, max {hi:.4}")?;
        }
        write!(
            f,
            "wrote {} files to {}",
            self.files.len(),
            self.out.display()
        )
    }
}

/// Reads `input` (its vertex colours replaced by `texture` under each vertex's UV when
/// given, [`texture::bake`]), computes every map and writes `saliency.ply` and one PNG per
/// map (`picture` pixels per view) into `out`, which must not exist or be empty (nothing
/// of the user's is overwritten; nothing is written when anything fails before).
pub fn saliency_file(
    input: &std::path::Path,
    out: &std::path::Path,
    views: &image::ViewParams,
    picture: u32,
    texture: Option<&std::path::Path>,
) -> Result<FileReport> {
    views.validate()?;
    if !(image::SIZE_RANGE.0..=image::SIZE_RANGE.1).contains(&picture) {
        return Err(Error::param(
            "saliency",
            "picture_size",
            picture,
            "must be between 16 and 4096 pixels",
        ));
    }
    if out.exists() {
        let empty = std::fs::read_dir(out)
            .map_err(|e| Error::io(out, e))?
            .next()
            .is_none();
        if !empty {
            return Err(Error::Usage(format!(
                "{}: the output directory exists and is not empty",
                out.display()
            )));
        }
    }
    let (mut m, _warnings) = crate::mesh::io::read_surface_with(input, &Default::default())?;
    m.validate("the input mesh")?;
    if let Some(t) = texture {
        texture::bake(&mut m, &texture::Texture::read(t)?).map_err(|e| match e {
            Error::Data { stage, message } => Error::Data {
                stage,
                message: format!("{}: {message}", input.display()),
            },
            e => e,
        })?;
    }
    if m.triangle_count() == 0 || m.area().partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return Err(Error::Data {
            stage: "saliency",
            message: format!("{}: the mesh has no area", input.display()),
        });
    }
    let t = std::time::Instant::now();
    let ms = mesh::mesh_saliency(&m);
    let mesh_seconds = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let img = image::image_saliency(&m, views)?;
    let image_seconds = t.elapsed().as_secs_f64();
    let maps = assemble(&m, ms, img);
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let mut files = vec![out.join("saliency.ply")];
    pictures::write_ply(&m, &maps, &files[0])?;
    for (name, col) in pictures::NAMES.iter().zip(pictures::columns(&maps)) {
        let p = out.join(format!("{name}.png"));
        pictures::write_png(&m, col, picture as usize, &p)?;
        files.push(p);
    }
    let mut classes = [0usize; 5];
    for &c in &maps.class {
        classes[c as usize] += 1;
    }
    let stats = pictures::NAMES
        .iter()
        .zip(pictures::columns(&maps))
        .map(|(n, c)| {
            let lo = c.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = c.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let mean = c.iter().sum::<f64>() / c.len().max(1) as f64;
            (n.to_string(), [lo, mean, hi])
        })
        .collect();
    Ok(FileReport {
        input: input.to_path_buf(),
        out: out.to_path_buf(),
        vertices: m.vertex_count(),
        triangles: m.triangle_count(),
        views: maps.image.views,
        mesh_seconds,
        image_seconds,
        classes,
        stats,
        files,
    })
}
