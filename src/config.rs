//! The `pipeline.toml` schema: one table per stage, each deserialised straight into that
//! stage's `…Params` struct (the TOML keys are the field names). Unknown keys and wrong
//! types are errors naming the file, line, column and dotted key.

use crate::error::{Error, Result};
use crate::points::{ClassFilter, Format, ReadOptions};
use crate::terrain::delaunay::BaselineParams;
use crate::terrain::{DenoiseParams, FillParams, ResampleParams};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// A whole pipeline file. `Default` is the pipeline with every table at its default and no
/// input (what the benchmarks run on a cloud they read themselves).
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Pipeline {
    /// `[input]`: which point clouds to read and how.
    pub input: InputConfig,
    /// `[output]`: where results go.
    #[serde(default)]
    pub output: crate::output::OutputConfig,
    /// `[tiles]`: how the heightfield is cut into tiles.
    #[serde(default)]
    pub tiles: crate::terrain::tiles::TileParams,
    /// `[quadtree]`: Röttger's constants.
    #[serde(default)]
    pub quadtree: crate::terrain::quadtree::QuadtreeParams,
    /// `[extract]`: how tile meshes and the wireframe preview are triangulated.
    #[serde(default)]
    pub extract: crate::terrain::extract::ExtractParams,
    /// `[denoise]`: the voxel-count noise filter (on by default).
    #[serde(default)]
    pub denoise: DenoiseParams,
    /// `[resample]`: the regular grid (√N × √N by default).
    #[serde(default)]
    pub resample: ResampleParams,
    /// `[fill]`: hole filling (on by default).
    #[serde(default)]
    pub fill: FillParams,
    /// `[ground]`: ground classification (off by default).
    #[serde(default)]
    pub ground: crate::terrain::ground::GroundParams,
    /// `[baseline]`: the Delaunay baseline and its comparison report (off by default).
    #[serde(default)]
    pub baseline: BaselineParams,
    /// `[[assets]]`: model meshes simplified and placed on the terrain (see `assets`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub assets: Vec<crate::assets::AssetConfig>,
    /// `[scale]`: in memory or streamed through temporary bricks (see `pipeline::stream`).
    #[serde(default)]
    pub scale: crate::shard::settings::ScaleConfig,
}

/// `[input]`
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct InputConfig {
    /// Files or glob patterns (`fixtures/*.las`), relative to the pipeline file's directory.
    /// All matches are read into one cloud: adjacent tiles of one survey.
    pub paths: Vec<String>,
    /// `auto` (default: recognised from the content), `las`, `laz` or `xyz`.
    #[serde(default)]
    pub format: FormatChoice,
    /// Keep only these ASPRS classes (e.g. `[2]` for ground); all when absent.
    #[serde(default)]
    pub keep_classes: Option<Vec<u8>>,
    /// Drop these classes (e.g. `[7, 18]`, low and high noise).
    #[serde(default)]
    pub drop_classes: Vec<u8>,
    /// Read at most this many points in all (the first ones, in file order).
    #[serde(default)]
    pub max_points: Option<u64>,
    /// The CRS of the input, `"EPSG:n"`, for files that state none (theirs wins otherwise).
    #[serde(default)]
    pub crs: Option<String>,
}

/// Input format choice.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FormatChoice {
    /// Recognise from the file's content.
    #[default]
    Auto,
    /// LAS.
    Las,
    /// LAZ.
    Laz,
    /// XYZ/CSV text.
    Xyz,
}

impl InputConfig {
    /// Reader options from this table.
    pub fn read_options(&self) -> ReadOptions {
        ReadOptions {
            format: match self.format {
                FormatChoice::Auto => None,
                FormatChoice::Las => Some(Format::Las),
                FormatChoice::Laz => Some(Format::Laz),
                FormatChoice::Xyz => Some(Format::Xyz),
            },
            classes: ClassFilter::new(self.keep_classes.as_deref(), &self.drop_classes),
            max_points: self.max_points,
            ..Default::default()
        }
    }
}

/// A loaded pipeline and where it came from.
#[derive(Debug, Clone)]
pub struct LoadedPipeline {
    /// The configuration.
    pub config: Pipeline,
    /// The file it was read from.
    pub path: PathBuf,
    /// Its text (to locate keys in later error messages).
    pub text: String,
}

impl LoadedPipeline {
    /// Directory relative paths are resolved against.
    pub fn base_dir(&self) -> PathBuf {
        self.path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .map_or_else(|| PathBuf::from("."), Path::to_path_buf)
    }

    /// The output directory, resolved.
    pub fn output_dir(&self) -> PathBuf {
        self.base_dir().join(&self.config.output.dir)
    }

    /// An error about `key` (dotted path) of this file, pointing at its line.
    pub fn key_error(&self, key: &str, message: impl Into<String>) -> Error {
        let (line, column) = locate_key(&self.text, key);
        Error::Config {
            path: self.path.clone(),
            line,
            column,
            key: key.to_string(),
            message: message.into(),
        }
    }

    /// A stage's `Param` error as an error at its key in this file (others unchanged).
    pub fn param_error(&self, e: Error) -> Error {
        match e {
            // A figure of the data rather than a key ("x range"): the file, then the stage.
            Error::Param {
                stage,
                param,
                value,
                message,
            } if param.contains(' ') => Error::Usage(format!(
                "{}: {stage}: {param} = {value}: {message}",
                self.path.display()
            )),
            Error::Param {
                stage,
                param,
                value,
                message,
            } => self.key_error(&format!("{stage}.{param}"), format!("{value}: {message}")),
            Error::Key { key, message } => self.key_error(&key, message),
            Error::Data { stage, message } => {
                Error::Usage(format!("{}: {stage}: {message}", self.path.display()))
            }
            other => other,
        }
    }

    /// The input files: every path and glob expanded, sorted within each pattern,
    /// duplicates removed. A pattern that matches nothing is an error.
    pub fn input_files(&self) -> Result<Vec<PathBuf>> {
        let base = self.base_dir();
        let mut out: Vec<PathBuf> = Vec::new();
        if self.config.input.paths.is_empty() {
            return Err(self.key_error(
                "input.paths",
                "no input given: list at least one file or glob",
            ));
        }
        for pat in &self.config.input.paths {
            let full = base.join(pat);
            let is_glob = pat.contains(['*', '?', '[']);
            if !is_glob {
                if let Some(why) = crate::fsutil::not_a_regular_file(&full) {
                    return Err(
                        self.key_error("input.paths", format!("input {} {why}", full.display()))
                    );
                }
                if !out.contains(&full) {
                    out.push(full);
                }
                continue;
            }
            let pattern = full.to_string_lossy().into_owned();
            let entries = glob::glob(&pattern)
                .map_err(|e| self.key_error("input.paths", format!("bad glob `{pat}`: {e}")))?;
            let mut matched: Vec<PathBuf> = entries
                .filter_map(|e| e.ok())
                .filter(|p| p.is_file())
                .collect();
            if matched.is_empty() {
                return Err(self.key_error("input.paths", format!("glob `{pat}` matches no file")));
            }
            matched.sort();
            for m in matched {
                if !out.contains(&m) {
                    out.push(m);
                }
            }
        }
        Ok(out)
    }
}

/// Reads and parses a pipeline file (the values are checked by the run's plan,
/// `pipeline::Plan`, before any work).
pub fn load(path: &Path) -> Result<LoadedPipeline> {
    let text = read_pipeline_text(path)?;
    let config = parse(path, &text)?;
    Ok(LoadedPipeline {
        config,
        path: path.to_path_buf(),
        text,
    })
}

/// Largest pipeline file read: 1 MiB (a real one is a few kilobytes).
pub const MAX_PIPELINE_BYTES: u64 = 1 << 20;

/// The text of a pipeline file: a regular file of at most [`MAX_PIPELINE_BYTES`], UTF-8.
fn read_pipeline_text(path: &Path) -> Result<String> {
    use std::io::Read;
    if let Some(why) = crate::fsutil::not_a_regular_file(path) {
        return Err(Error::Usage(format!(
            "{}: pipeline file {why}",
            path.display()
        )));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut bytes = Vec::new();
    file.take(MAX_PIPELINE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > MAX_PIPELINE_BYTES {
        return Err(Error::Usage(format!(
            "{}: pipeline file is larger than {} bytes (1 MiB); a pipeline file is a few kilobytes of TOML",
            path.display(),
            MAX_PIPELINE_BYTES
        )));
    }
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let text = String::from_utf8_lossy(&e.as_bytes()[..at]).into_owned();
        let (line, column) = line_col(&text, text.len());
        Error::Config {
            path: path.to_path_buf(),
            line,
            column,
            key: "(syntax)".into(),
            message: format!("byte {at} is not UTF-8"),
        }
    })
}

impl LoadedPipeline {
    /// Checks the stage parameters serde cannot (ranges, combinations) before any data is
    /// read; an error names the file, line and dotted key, then the value and what is wrong.
    pub fn check_stages(&self) -> Result<()> {
        let c = &self.config;
        let at_key = |e: Error| self.param_error(e);
        if c.input.max_points == Some(0) {
            return Err(self.key_error("input.max_points", "0: must be at least 1"));
        }
        if let Some(Err(e)) = c.input.crs.as_deref().map(crate::geo::crs_from_key) {
            let shown = crate::error::one_line(c.input.crs.as_deref().unwrap_or_default());
            return Err(self.key_error("input.crs", format!("\"{shown}\": {e}")));
        }
        c.denoise.validate().map_err(at_key)?;
        c.resample.validate().map_err(at_key)?;
        c.fill.validate().map_err(at_key)?;
        c.ground.validate().map_err(at_key)?;
        c.tiles.validate().map_err(at_key)?;
        c.quadtree.validate().map_err(at_key)?;
        c.extract.validate().map_err(at_key)?;
        c.output.validate().map_err(at_key)?;
        c.baseline.validate().map_err(at_key)?;
        c.scale.validate().map_err(at_key)
    }
}

/// Parses pipeline text; `path` is only used in error messages.
pub fn parse(path: &Path, text: &str) -> Result<Pipeline> {
    let at = |span: Option<std::ops::Range<usize>>| {
        let offset = span.map_or(0, |s| s.start).min(text.len());
        line_col(text, offset)
    };
    let de = toml::Deserializer::parse(text).map_err(|e| {
        let (line, column) = at(e.span());
        Error::Config {
            path: path.to_path_buf(),
            line,
            column,
            key: "(syntax)".into(),
            message: e.message().trim().to_string(),
        }
    })?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let mut key = e.path().to_string();
        let inner = e.into_inner();
        let message = inner.message().trim().to_string();
        // serde names the parent table for unknown fields; add the field itself.
        if let Some(rest) = message.strip_prefix("unknown field `") {
            if let Some(name) = rest.split('`').next().filter(|n| !key.ends_with(n)) {
                key = if key == "." || key.is_empty() {
                    name.to_string()
                } else {
                    format!("{key}.{name}")
                };
            }
        }
        if key == "." {
            key = "(top level)".into();
        }
        let (line, column) = at(inner.span());
        Error::Config {
            path: path.to_path_buf(),
            line,
            column,
            key,
            message,
        }
    })
}

/// 1-based line and column of byte `offset`.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let column = before.rfind('\n').map_or(offset, |p| offset - p - 1) + 1;
    (line, column)
}

/// Line and column of `key = …` for a dotted key `table.key` (line 1 if not written, i.e.
/// a default value is at fault).
pub fn locate_key(text: &str, dotted: &str) -> (usize, usize) {
    if let Some((array, rest)) = dotted.split_once('[') {
        if let Some((index, path)) = rest.split_once(']') {
            if let Ok(index) = index.parse::<usize>() {
                return locate_array_key(text, array, index, path.trim_start_matches('.'));
            }
        }
    }
    let (table, key) = dotted.rsplit_once('.').unwrap_or(("", dotted));
    let mut current = String::new();
    let mut table_line = None;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if let Some(h) = line.strip_prefix('[') {
            current = h
                .trim_start_matches('[')
                .split(']')
                .next()
                .unwrap_or("")
                .trim()
                .to_string();
            if current == table {
                table_line = Some(i + 1);
            }
            continue;
        }
        if current == table {
            if let Some(rest) = line.strip_prefix(key) {
                if rest.trim_start().starts_with('=') {
                    let col = raw.len() - raw.trim_start().len() + 1;
                    return (i + 1, col);
                }
            }
        }
    }
    (table_line.unwrap_or(1), 1)
}

/// Line and column of `path` (e.g. `simplify.ratio`) inside the `index`-th `[[array]]`
/// entry: a `key =` line under `[array.simplify]`, or inside an inline table
/// `simplify = { … ratio = … }`; else the entry's header line.
fn locate_array_key(text: &str, array: &str, index: usize, path: &str) -> (usize, usize) {
    let (table, key) = path.rsplit_once('.').unwrap_or(("", path));
    let header = format!("[[{array}]]");
    let sub = format!("[{array}.{table}]");
    let mut seen = 0usize;
    let mut entry_line = None;
    let mut section = String::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.starts_with('[') {
            if line.starts_with(&header) {
                seen += 1;
                if seen == index + 1 {
                    entry_line = Some(i + 1);
                } else if entry_line.is_some() {
                    break;
                }
                section.clear();
            } else {
                section = line.to_string();
            }
            continue;
        }
        if entry_line.is_none() || key.is_empty() {
            continue;
        }
        let col = raw.len() - raw.trim_start().len() + 1;
        let starts = |l: &str, k: &str| {
            l.strip_prefix(k)
                .is_some_and(|r| r.trim_start().starts_with('='))
        };
        if (table.is_empty() && section.is_empty()
            || !table.is_empty() && section.starts_with(&sub))
            && starts(line, key)
        {
            return (i + 1, col);
        }
        if !table.is_empty() && section.is_empty() && starts(line, table) {
            let inner = format!("{key} ");
            let inner_eq = format!("{key}=");
            if let Some(p) = raw.find(&inner).or_else(|| raw.find(&inner_eq)) {
                return (i + 1, p + 1);
            }
            return (i + 1, col);
        }
    }
    (entry_line.unwrap_or(1), 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_key_and_wrong_type_name_line_and_key() {
        for (text, start) in [
            (
                "[input]\npaths = [\"a.las\"]\ncolour = 3\n",
                "p.toml:3:1: input.colour: unknown field `colour`",
            ),
            (
                "[input]\npaths = [\"a.las\"]\nmax_points = \"many\"\n",
                "p.toml:3:14: input.max_points: invalid type",
            ),
        ] {
            let e = parse(Path::new("p.toml"), text).unwrap_err().to_string();
            assert!(e.starts_with(start), "{e}");
        }
    }

    #[test]
    fn locate_finds_keys_in_array_entries() {
        let text =
            "[input]\npaths = []\n[[assets]]\ninput = \"a.obj\"\n[[assets]]\ninput = \"b.obj\"\n\
                    simplify = { method = \"octree\", ratio = 3 }\n[assets.place]\nx = 1\n";
        assert_eq!(locate_key(text, "assets[1].input"), (6, 1));
        assert_eq!(locate_key(text, "assets[1].simplify.ratio"), (7, 33));
        assert_eq!(locate_key(text, "assets[1].place.x"), (9, 1));
        assert_eq!(locate_key(text, "assets[0].place.x"), (3, 1));
    }

    #[test]
    fn locate_finds_keys_in_tables() {
        let text = "[input]\npaths = []\n[output]\n  dir = \"x\"\n";
        assert_eq!(locate_key(text, "output.dir"), (4, 3));
        assert_eq!(locate_key(text, "output.other"), (3, 1));
    }
}
