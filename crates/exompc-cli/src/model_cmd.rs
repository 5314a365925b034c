//! `exompc model`.
use clap::Args;
use exompc_cli::error::CliError;

#[derive(Debug, Args)]
pub(crate) struct ModelArgs {}

pub(crate) fn run(_a: ModelArgs) -> Result<(), CliError> {
    crate::not_implemented("model")
}
