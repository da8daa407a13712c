//! `vidslam config`: print the effective configuration.

use crate::runtime::Config;
use clap::Args;
use std::path::PathBuf;

/// Prints the configuration as TOML: every key with its value — the defaults, or FILE with the
/// defaults filled in (after checking it: errors name the line and the key).
#[derive(Args, Debug)]
pub struct ConfigArgs {
    /// A configuration file to check and complete.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

pub fn run(a: ConfigArgs) -> anyhow::Result<()> {
    let cfg = Config::read_or_default(a.config.as_deref())?;
    print!("{}", cfg.to_toml());
    Ok(())
}
