//! `exompc plot`.
use clap::Args;
use exompc_cli::error::CliError;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub(crate) struct PlotArgs {
    /// Folder written by `simulate` or `sweep`.
    #[arg(value_name = "DIR")]
    input: Option<PathBuf>,
}

pub(crate) fn run(a: PlotArgs) -> Result<(), CliError> {
    let _ = a.input;
    crate::not_implemented("plot")
}

/// Draw the figures of the traces in `dir`.
pub(crate) fn draw_dir(_dir: &std::path::Path) -> Result<(), CliError> {
    crate::not_implemented("plot")
}
