//! `optistim sim-lab`: the simulated facility camera's lab products.

use std::path::PathBuf;

use anyhow::Result;

use optistim::simfacility::SimFacility;

/// Arguments of `optistim sim-lab`.
#[derive(clap::Args)]
pub struct SimLabArgs {
    /// Simulated facility file (TOML, docs/SIMFACILITY.md).
    #[arg(long)]
    pub sim_facility: PathBuf,
    /// Output directory (created).
    #[arg(long)]
    pub out: PathBuf,
}

/// `optistim sim-lab`.
pub fn sim_lab(args: &SimLabArgs) -> Result<()> {
    let sim = SimFacility::load(&args.sim_facility)?;
    let files = sim.write_lab_camera_files(&args.out)?;
    for p in [
        &files.intrinsics,
        &files.camera_flat,
        &files.camera_flat_uncertainty,
        &files.responsivity,
    ] {
        println!("{}", p.display());
    }
    Ok(())
}
