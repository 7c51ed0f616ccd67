//! Ground classification of whole files: `terratile classify IN OUT` and the pipeline's
//! `[ground]` stage share these. The classification itself is [`crate::terrain::ground`];
//! this module reads, decides what to trust, scores and writes.
//!
//! The classified file is an uncompressed LAS with the input's records in the input's order
//! and point format, byte for byte, only the class changed: 2 for ground, 1 for every other
//! point. XYZ text has no class field to keep, so it is refused (exit 2) rather than turned
//! into a LAS with made-up attributes.

use crate::error::{Error, Result};
use crate::points::{self, Format, PointCloud, ReadOptions};
use crate::terrain::ground::{self, GroundParams, GroundSettings, Scores};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The classified points' file in the output directory (`ground.write_classified`).
pub const CLASSIFIED_FILE: &str = "classified.las";
/// ASPRS class of ground points.
pub const GROUND_CLASS: u8 = 2;
/// ASPRS class written for every point that is not ground ("unclassified").
pub const OTHER_CLASS: u8 = 1;

/// What a classification did.
#[derive(Debug, Clone, Serialize)]
pub struct ClassifyReport {
    /// Points classified.
    pub points: usize,
    /// Points found to be ground.
    pub ground: usize,
    /// Seconds of the classification (not the reading or writing).
    pub seconds: f64,
    /// `true` when the file's own class 2 was taken (`trust_existing`).
    pub trusted_existing: bool,
    /// The settings used (None when the existing classes were trusted).
    pub settings: Option<GroundSettings>,
    /// Scores against the file's own class 2 (`--score`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub score: Option<Scores>,
    /// The classified file written.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub output: Option<PathBuf>,
}

/// The ground flags of `cloud`'s points (those `keep` flags, all when None): the file's own
/// class 2 when `trust_existing` is set and the cloud has class 2 points, otherwise ours.
pub fn ground_of(
    cloud: &PointCloud,
    keep: Option<&[bool]>,
    params: &GroundParams,
) -> Result<(Vec<bool>, ClassifyReport)> {
    let t = Instant::now();
    let has_class2 = cloud.classification.contains(&GROUND_CLASS);
    if params.trust_existing && has_class2 {
        let g: Vec<bool> = cloud
            .classification
            .iter()
            .enumerate()
            .map(|(i, &c)| c == GROUND_CLASS && keep.is_none_or(|k| k[i]))
            .collect();
        let n = g.iter().filter(|v| **v).count();
        let report = ClassifyReport {
            points: keep.map_or(cloud.len(), |k| k.iter().filter(|v| **v).count()),
            ground: n,
            seconds: t.elapsed().as_secs_f64(),
            trusted_existing: true,
            settings: None,
            score: None,
            output: None,
        };
        return Ok((g, report));
    }
    let mpu = cloud.crs().map_or(1.0, |c| c.metres_per_unit());
    let g = ground::classify(&cloud.x, &cloud.y, &cloud.z, keep, params, mpu)?;
    let report = ClassifyReport {
        points: keep.map_or(cloud.len(), |k| k.iter().filter(|v| **v).count()),
        ground: g.ground_count,
        seconds: t.elapsed().as_secs_f64(),
        trusted_existing: false,
        settings: Some(g.settings),
        score: None,
        output: None,
    };
    Ok((g.ground, report))
}

/// Refuses an output the classified file may not be written to: the input itself (by path
/// or as the same file), an existing file (terratile did not write it), or a name that
/// promises compression (the file is plain LAS).
pub fn check_output(input: &Path, output: &Path) -> Result<()> {
    let same = output == input
        || matches!(
            (input.canonicalize(), output.canonicalize()),
            (Ok(a), Ok(b)) if a == b
        );
    if same {
        return Err(Error::Usage(format!(
            "{}: the classified output is the input file; choose another name",
            output.display()
        )));
    }
    if output.symlink_metadata().is_ok() {
        return Err(Error::Usage(format!(
            "{}: already exists; terratile does not replace a file it did not write",
            output.display()
        )));
    }
    let ext = output
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    if ext.as_deref() == Some("laz") {
        return Err(Error::Usage(format!(
            "{}: the classified file is written as uncompressed LAS; name it .las",
            output.display()
        )));
    }
    Ok(())
}

/// The class written for each point: 2 where `ground` is set, 1 elsewhere.
fn classes_of(ground: &[bool]) -> Vec<u8> {
    ground
        .iter()
        .map(|&g| if g { GROUND_CLASS } else { OTHER_CLASS })
        .collect()
}

/// Writes `cloud`'s records with class 2 where `ground` is set and 1 elsewhere (see the
/// module's notes). `opts` are the options the cloud was read with.
pub fn write_classified(
    path: &Path,
    cloud: &PointCloud,
    opts: &ReadOptions,
    ground: &[bool],
) -> Result<()> {
    if let Some(s) = cloud.sources.iter().find(|s| s.format == Format::Xyz) {
        return Err(Error::Usage(format!(
            "{}: XYZ text has no classification field; a classified file needs LAS or LAZ input",
            s.path.display()
        )));
    }
    if !points::write_reclassified_records(path, &cloud.sources, opts, &classes_of(ground))? {
        return Err(Error::Usage(format!(
            "{}: the inputs differ in point format, record length, scale or offset; a classified file needs one layout",
            path.display()
        )));
    }
    Ok(())
}

/// `terratile classify`: classifies `input` and writes the classified LAS to `output` (when
/// given), scoring against the file's own class 2 when `score` is set.
pub fn classify_file(
    input: &Path,
    output: Option<&Path>,
    params: &GroundParams,
    score: bool,
    progress: &dyn crate::progress::Progress,
) -> Result<ClassifyReport> {
    params.validate()?;
    if let Some(o) = output {
        check_output(input, o)?;
    }
    let opts = ReadOptions::default();
    // With an output, a LAZ file's decompressed records are kept for the writer: decoding
    // the file a second time cost about a third of the command's time.
    let (cloud, mut raw) = match output {
        Some(_) => points::read_keeping_records(input, &opts, progress)?,
        None => (points::read(input, &opts, progress)?, None),
    };
    if let Some(o) = output {
        if cloud.sources.iter().any(|s| s.format == Format::Xyz) {
            return Err(Error::Usage(format!(
                "{}: XYZ text has no classification field; a classified file needs LAS or LAZ input ({})",
                input.display(),
                o.display()
            )));
        }
    }
    let truth: Option<Vec<bool>> = if score {
        if !cloud.classification.contains(&GROUND_CLASS) {
            return Err(Error::Usage(format!(
                "{}: --score needs the file's own ground class (2); it has no class 2 point",
                input.display()
            )));
        }
        Some(
            cloud
                .classification
                .iter()
                .map(|&c| c == GROUND_CLASS)
                .collect(),
        )
    } else {
        None
    };
    let (ground, mut report) = ground_of(&cloud, None, params)?;
    report.score = truth.map(|t| Scores::of(&ground, &t));
    if let Some(o) = output {
        progress.start("writing", 0);
        let w = match raw.as_mut() {
            Some(raw) => {
                drop(cloud);
                points::write_reclassified_raw(o, raw, &classes_of(&ground))
            }
            None => write_classified(o, &cloud, &opts, &ground),
        };
        progress.finish();
        w?;
        report.output = Some(o.to_path_buf());
    }
    Ok(report)
}
