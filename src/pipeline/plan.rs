//! The plan of a run: the pipeline file checked in one pass before any work — every stage's
//! and encoder's parameters, the input files, the `[[assets]]` entries and the names the run
//! will write — each complaint an [`Error`](crate::Error) located at its key in the file;
//! then the output directory checked, locked and staged, before a point is read.

use crate::config::LoadedPipeline;
use crate::error::Result;
use crate::fsutil::{Keep, StagedDir};
use std::path::PathBuf;

/// A checked pipeline: its file and the input files it names.
#[derive(Debug)]
pub struct Plan<'a> {
    /// The pipeline file.
    pub pipeline: &'a LoadedPipeline,
    /// The input files, every glob expanded.
    pub inputs: Vec<PathBuf>,
}

impl<'a> Plan<'a> {
    /// Checks `pipeline` in one pass: the stages and encoders, the inputs, the assets and
    /// the output names, every error at its key.
    pub fn new(pipeline: &'a LoadedPipeline) -> Result<Plan<'a>> {
        pipeline.check_stages()?;
        let inputs = pipeline.input_files()?;
        let cfg = &pipeline.config;
        let at_key = |e| pipeline.param_error(e);
        crate::assets::validate(&cfg.assets, &pipeline.base_dir()).map_err(at_key)?;
        crate::outnames::check(cfg).map_err(at_key)?;
        Ok(Plan { pipeline, inputs })
    }

    /// The output directory checked, locked and staged, before any point is read. The
    /// pipeline file, the inputs and the asset inputs are kept out of harm's way.
    pub fn stage_output_dir(&self) -> Result<StagedDir> {
        let pipeline = self.pipeline;
        let out_dir = pipeline.output_dir();
        let base = pipeline.base_dir();
        let asset_inputs: Vec<PathBuf> = pipeline
            .config
            .assets
            .iter()
            .map(|a| base.join(&a.input))
            .collect();
        let mut keep = vec![Keep {
            what: "pipeline file",
            path: &pipeline.path,
        }];
        keep.extend(self.inputs.iter().map(|path| Keep {
            what: "input file",
            path,
        }));
        keep.extend(asset_inputs.iter().map(|path| Keep {
            what: "asset input",
            path,
        }));
        StagedDir::new(&out_dir, &base, &keep)
    }
}
