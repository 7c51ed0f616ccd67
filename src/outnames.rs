//! The names a run writes into its output directory, checked against each other before any
//! work: an `[[assets]]` output, a baseline file, the tiles, the manifest, the previews,
//! `noise.las` and the marker may not overwrite one another, nor need a file as a directory
//! (`baseline.report = "tiles"` while `tiles/` is written). Names compare without regard to
//! case, as on the file systems of macOS and Windows.

use crate::config::Pipeline;
use crate::error::{Error, Result};

/// The removed-noise file written with `denoise.write_removed = true`.
pub const NOISE_FILE: &str = "noise.las";

/// A name the run writes whatever the data: (dotted key that turns it on, path).
fn fixed(cfg: &Pipeline) -> Vec<(&'static str, &'static str)> {
    let o = &cfg.output;
    let mut v = vec![("(terratile's marker)", crate::fsutil::MARKER)];
    if o.manifest {
        v.push(("output.manifest", "manifest.json"));
    }
    if o.relief {
        v.push(("output.relief", "preview/relief.png"));
    }
    if o.wireframe {
        v.push(("output.wireframe", "preview/wireframe.png"));
    }
    if cfg.denoise.enabled && cfg.denoise.write_removed {
        v.push(("denoise.write_removed", NOISE_FILE));
    }
    v
}

/// A directory of per-tile files: (key, directory, what, file name extensions written).
fn tile_dirs(cfg: &Pipeline) -> Vec<(&'static str, &'static str, &'static str, Vec<&'static str>)> {
    let o = &cfg.output;
    let mut v = Vec::new();
    if o.exr {
        v.push(("output.exr", "tiles", "EXR tiles", vec!["exr"]));
    }
    if o.png || o.raw {
        let key = if o.png { "output.png" } else { "output.raw" };
        v.push((key, "heightmaps", "heightmaps", vec!["png", "raw", "r16"]));
    }
    if !o.meshes.is_empty() {
        v.push((
            "output.meshes",
            "meshes",
            "tile meshes",
            o.meshes.iter().map(|f| f.ext()).collect(),
        ));
    }
    if o.relief || o.wireframe {
        let key = if o.relief {
            "output.relief"
        } else {
            "output.wireframe"
        };
        v.push((key, "preview", "previews", Vec::new()));
    }
    v
}

/// True for `tile_C_R.EXT` (C, R decimal) and, in `heightmaps`, `landscape.EXT`.
fn is_tile_file(name: &str, exts: &[&str]) -> bool {
    let Some((stem, ext)) = name.rsplit_once('.') else {
        return false;
    };
    if !exts.contains(&ext) {
        return false;
    }
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    stem == "landscape"
        || stem
            .strip_prefix("tile_")
            .and_then(|r| r.split_once('_'))
            .is_some_and(|(c, r)| digits(c) && digits(r))
}

/// Lower-cased normal components of a relative output name.
fn parts(name: &str) -> Vec<String> {
    std::path::Path::new(name)
        .components()
        .filter_map(|c| match c {
            std::path::Component::Normal(n) => Some(n.to_string_lossy().to_lowercase()),
            _ => None,
        })
        .collect()
}

/// Checks every freely named output (baseline mesh and report, asset outputs) against every
/// other output. The error is (dotted key, message).
pub fn check(cfg: &Pipeline) -> Result<()> {
    let mut free: Vec<(String, String)> = Vec::new();
    if cfg.baseline.enabled {
        if !cfg.baseline.mesh.is_empty() {
            free.push(("baseline.mesh".into(), cfg.baseline.mesh.clone()));
        }
        free.push(("baseline.report".into(), cfg.baseline.report.clone()));
    }
    for (i, a) in cfg.assets.iter().enumerate() {
        free.push((
            format!("assets[{i}].output"),
            a.output.to_string_lossy().into_owned(),
        ));
    }
    let mut taken: Vec<(String, Vec<String>)> = fixed(cfg)
        .into_iter()
        .map(|(k, n)| (k.to_string(), parts(n)))
        .collect();
    let dirs = tile_dirs(cfg);
    for (key, name) in free {
        let p = parts(&name);
        let err = |msg: String| {
            Err(Error::key(
                key.clone(),
                format!("`{name}` {msg}; choose another name"),
            ))
        };
        if p.is_empty() {
            return err("names no file inside the output directory".into());
        }
        for (dkey, dir, what, exts) in &dirs {
            if p.len() == 1 && p[0] == *dir {
                return err(format!(
                    "is the directory of the {what} ({dkey} writes {dir}/)"
                ));
            }
            if p.len() == 2 && p[0] == *dir && is_tile_file(&p[1], exts) {
                return err(format!(
                    "would overwrite one of the {what} ({dkey} writes {dir}/tile_C_R.{})",
                    exts.first().copied().unwrap_or("…")
                ));
            }
        }
        for (other, q) in &taken {
            if *q == p {
                return err(format!("is also written by {other}"));
            }
            let n = p.len().min(q.len());
            if p[..n] == q[..n] {
                let (file, dir) = if p.len() < q.len() {
                    ("it", other.as_str())
                } else {
                    (other.as_str(), "it")
                };
                return err(format!(
                    "and {other} cannot both be written: {dir} needs a directory where {file} \
                     writes a file"
                ));
            }
        }
        taken.push((key.clone(), p));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The key and message of a check's error.
    fn key_of(e: Error) -> (String, String) {
        match e {
            Error::Key { key, message } => (key, message),
            other => panic!("not a key error: {other}"),
        }
    }

    fn cfg(extra: &str) -> Pipeline {
        let text = format!("[input]\npaths = [\"a.las\"]\n{extra}");
        crate::config::parse(std::path::Path::new("p.toml"), &text).unwrap()
    }

    fn asset(out: &str) -> String {
        format!(
            "[[assets]]\ninput = \"m.obj\"\noutput = \"{out}\"\nplace = {{ x = 0.0, y = 0.0 }}\n"
        )
    }

    #[test]
    fn tile_names_and_directories_are_taken() {
        // PLY tile meshes asked for (the default is glb alone).
        let e = check(&cfg(&format!(
            "[output]\nmeshes = [\"ply\"]\n{}",
            asset("meshes/tile_000_000.ply")
        )))
        .unwrap_err();
        let e = key_of(e);
        assert_eq!(e.0, "assets[0].output");
        assert!(e.1.contains("output.meshes"), "{e:?}");
        let e = check(&cfg(&asset("Tiles/tile_12_3.EXR"))).unwrap_err();
        let e = key_of(e);
        assert!(e.1.contains("output.exr"), "{e:?}");
        let e = check(&cfg("[baseline]\nenabled = true\nreport = \"tiles\"\n")).unwrap_err();
        let e = key_of(e);
        assert_eq!(e.0, "baseline.report");
        assert!(e.1.contains("directory of the EXR tiles"), "{e:?}");
        // Not a tile's name, or the switch is off: allowed.
        check(&cfg(&asset("meshes/house.ply"))).unwrap();
        check(&cfg(&format!(
            "[output]\nmeshes = []\n{}",
            asset("meshes/tile_000_000.ply")
        )))
        .unwrap();
    }

    #[test]
    fn fixed_names_and_each_other() {
        let e = check(&cfg(&asset("manifest.json/a.obj"))).unwrap_err();
        let e = key_of(e);
        assert!(e.1.contains("output.manifest"), "{e:?}");
        let e = check(&cfg(&asset("preview/relief.png"))).unwrap_err();
        let e = key_of(e);
        assert!(e.1.contains("output.relief"), "{e:?}");
        let two = format!("{}{}", asset("a/rock.ply"), asset("./A/rock.ply"));
        let e = check(&cfg(&two)).unwrap_err();
        let e = key_of(e);
        assert_eq!(e.0, "assets[1].output");
        assert!(e.1.contains("assets[0].output"), "{e:?}");
        let e = check(&cfg(&format!(
            "[baseline]\nenabled = true\nreport = \"x\"\n{}",
            asset("x/rock.ply")
        )))
        .unwrap_err();
        let e = key_of(e);
        assert!(e.1.contains("baseline.report"), "{e:?}");
        check(&cfg(&format!(
            "{}{}",
            asset("a/rock.ply"),
            asset("b/rock.ply")
        )))
        .unwrap();
    }
}
