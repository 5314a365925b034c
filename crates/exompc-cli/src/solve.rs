//! `exompc solve`.
use clap::Args;
use exompc_cli::error::CliError;

#[derive(Debug, Args)]
pub(crate) struct SolveArgs {}

pub(crate) fn run(_a: SolveArgs) -> Result<(), CliError> {
    crate::not_implemented("solve")
}
