//! `exompc soak`.
use crate::ConfigOpt;
use clap::Args;
use exompc_cli::error::CliError;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub(crate) struct SoakArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

pub(crate) fn run(a: SoakArgs) -> Result<(), CliError> {
    let _scenario = a.config.load()?;
    if let Some(out) = &a.out {
        exompc_cli::io::ensure_out_dir(out)?;
    }
    crate::not_implemented("soak")
}
