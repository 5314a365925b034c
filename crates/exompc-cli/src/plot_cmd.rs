//! `exompc plot`: draw the figures of a results folder.

use crate::plot::draw_dir;
use clap::Args;
use exompc_cli::error::CliError;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub(crate) struct PlotArgs {
    /// Folder written by `simulate` (trace.csv) or `sweep` (sweep.json).
    #[arg(value_name = "DIR", default_value = "out/simulate")]
    input: PathBuf,
}

pub(crate) fn run(a: PlotArgs) -> Result<(), CliError> {
    let files = draw_dir(&a.input)?;
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}
