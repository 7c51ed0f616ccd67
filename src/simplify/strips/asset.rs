//! `strips = { … }` in an `[[assets]]` entry: the placed asset also written as a
//! progressive-strips stream, and optionally one level of it as a glTF `TRIANGLE_STRIP`.
//!
//! ```toml
//! strips = { output = "assets/rock.tps", base_ratio = 0.05, glb = "assets/rock_strip.glb", level = 0 }
//! ```

use super::format::{encode, glb_at, BuildReport};
use super::{progressive, Encoding, ProgressiveParams, StripOrder};
use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// One asset's `strips` table.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct AssetStrips {
    /// The `.tps` stream to write, relative to the output directory.
    pub output: PathBuf,
    /// The base mesh's share of the triangles, in (0, 1) (default 0.05, as the paper).
    #[serde(default = "default_base_ratio")]
    pub base_ratio: f64,
    /// The split records' form, `encoded` (E-PS, default) or `naive`.
    #[serde(default)]
    pub encoding: Encoding,
    /// The full strip's order, `hierarchical` (default) or `paper`.
    #[serde(default)]
    pub order: StripOrder,
    /// A `.glb` with one `TRIANGLE_STRIP` primitive of the level `level`, relative to the
    /// output directory (none by default).
    #[serde(default)]
    pub glb: Option<PathBuf>,
    /// The level the `.glb` holds: splits applied, 0 for the base mesh (default: all).
    #[serde(default)]
    pub level: Option<usize>,
}

fn default_base_ratio() -> f64 {
    0.05
}

impl AssetStrips {
    /// Checks the values before any work; `key` names the table (`assets[0].strips`).
    /// `inside` says whether a path stays inside the output directory.
    pub fn validate(&self, key: &str, inside: impl Fn(&Path) -> bool) -> Result<()> {
        let r = self.base_ratio;
        if !(r > 0.0 && r < 1.0) {
            return Err(Error::key(
                format!("{key}.base_ratio"),
                format!("{r} must be a number in (0, 1)"),
            ));
        }
        let files = [("output", Some(&self.output), "tps")];
        let glb = [("glb", self.glb.as_ref(), "glb")];
        for (name, path, ext) in files.into_iter().chain(glb) {
            let Some(path) = path else { continue };
            if path.extension().and_then(|e| e.to_str()) != Some(ext) {
                return Err(Error::key(
                    format!("{key}.{name}"),
                    format!("{} must end in .{ext}", path.display()),
                ));
            }
            if !inside(path) {
                return Err(Error::key(
                    format!("{key}.{name}"),
                    "must be a relative path inside the output directory",
                ));
            }
        }
        if self.level.is_some() && self.glb.is_none() {
            return Err(Error::key(
                format!("{key}.level"),
                "is the level of `glb`, which is not given",
            ));
        }
        Ok(())
    }

    /// Builds the progressive strips of `mesh` (the placed asset) and writes the stream and
    /// the `.glb` under `out_dir`; `input` names the asset in messages.
    pub fn write(&self, mesh: &TriMesh, input: &Path, out_dir: &Path) -> Result<BuildReport> {
        let params = ProgressiveParams {
            base_ratio: self.base_ratio,
            order: self.order,
            ..ProgressiveParams::default()
        };
        let p = progressive(mesh, &params)?;
        let write = |path: &Path, data: &[u8]| {
            let out = out_dir.join(path);
            if let Some(parent) = out.parent() {
                std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
            }
            crate::fsutil::write_bytes_atomic(&out, data)
        };
        // The .glb first: a level past the stream is refused before anything is written.
        if let Some(glb) = &self.glb {
            let level = self.level.unwrap_or(p.splits.len());
            if level > p.splits.len() {
                return Err(Error::Data {
                    stage: "assets",
                    message: format!(
                        "{}: strips.level {level} is past the stream's {} splits",
                        input.display(),
                        p.splits.len()
                    ),
                });
            }
            let name = glb
                .file_stem()
                .map_or("mesh".into(), |s| s.to_string_lossy());
            write(glb, &glb_at(&p, level, self.encoding, &name, 1.0)?)?;
        }
        let bytes = encode(&p, self.encoding);
        write(&self.output, &bytes)?;
        Ok(BuildReport::of(&p, bytes.len()))
    }
}
