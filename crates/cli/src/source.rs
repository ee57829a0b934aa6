//! Where a network description comes from: a built-in preset or a file.

use anyhow::{Result, bail};
use ecsync_sim::SlaveSpec;
use std::path::PathBuf;

/// `--preset NAME` or `--config FILE`.
#[derive(Debug, Clone, clap::Args)]
pub struct SourceArgs {
    /// Built-in network, by the name of its file in the repository's presets/: paper-2024,
    /// twelve-drives, akd, lan9252-pair, ek1100-el2828-el2889 or oversampling.
    #[arg(long, conflicts_with = "config")]
    pub preset: Option<String>,
    /// A TOML file describing the network (see presets/paper-2024.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

impl SourceArgs {
    /// The TOML text and a name for messages.
    pub fn load(&self) -> Result<(String, String)> {
        match (&self.preset, &self.config) {
            (_, Some(path)) => {
                let text = ecsync_sim::config::read_text(path).map_err(anyhow::Error::msg)?;
                Ok((path.display().to_string(), text))
            }
            (Some(name), None) => match ecsync_sim::preset::named(name) {
                Some(t) => Ok((format!("preset {name}"), t.to_string())),
                None => bail!(
                    "unknown preset \"{name}\"; the built-in presets are: {}",
                    ecsync_sim::preset::names()
                ),
            },
            (None, None) => Ok((
                "preset paper-2024".to_string(),
                ecsync_sim::preset::PAPER_2024_TOML.to_string(),
            )),
        }
    }

    /// The whole scenario (the segment, `[run]`, `[host]`...), checked as `compare` checks
    /// the file.
    pub fn scenario(&self) -> Result<(String, ecsync_lab::Scenario)> {
        let (name, text) = self.load()?;
        let s = ecsync_lab::parse(&name, &text).map_err(anyhow::Error::msg)?;
        Ok((name, s))
    }

    /// The segment's slaves and the names the scenario gives them.
    pub fn segment_named(&self) -> Result<(String, Vec<SlaveSpec>, Vec<String>)> {
        let (name, text) = self.load()?;
        let s = ecsync_lab::parse(&name, &text).map_err(anyhow::Error::msg)?;
        Ok((name, s.slaves, s.slave_names))
    }
}
