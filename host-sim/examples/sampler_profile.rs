//! Profiling aid: one default-world dataset, one sampler variant, a few sweeps.
use host_sim::sampling::{run_sampler, SamplingConfig, Variant};
use host_sim::sim::{simulate, SimConfig};

fn main() -> anyhow::Result<()> {
    let v = match std::env::args().nth(1).as_deref() {
        Some("l1") => Variant::L1,
        Some("l9") => Variant::L9,
        _ => Variant::L9Border,
    };
    let world = host_sim::world::generate::default_world();
    let run = simulate(&world, &SimConfig::default(), 1)?;
    let shift: u8 = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(4);
    let k: u8 = std::env::args()
        .nth(3)
        .and_then(|s| s.parse().ok())
        .unwrap_or(16);
    let cfg = SamplingConfig {
        burn_in: 0,
        sweeps: 10,
        tile_shift: shift,
        max_candidates: k,
        ..SamplingConfig::default()
    };
    let o = run_sampler(
        run.geometry,
        &run.mapper_config,
        &run.scans,
        &run.map,
        v,
        &cfg,
        1,
    )?;
    println!(
        "{}: {:.4} s per sweep, stats {:?}",
        v.name(),
        o.seconds_per_sweep,
        o.stats
    );
    Ok(())
}
