//! `exompc bench`.
use crate::ConfigOpt;
use clap::Args;
use exompc_cli::error::CliError;

#[derive(Debug, Args)]
pub(crate) struct BenchArgs {
    #[command(flatten)]
    config: ConfigOpt,
}

pub(crate) fn run(a: BenchArgs) -> Result<(), CliError> {
    let _scenario = a.config.load()?;
    crate::not_implemented("bench")
}
