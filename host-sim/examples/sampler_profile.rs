//! Profiling aid: one default-world dataset, one sampler variant, ten sweeps.
//!
//! `cargo run --release -p host-sim --example sampler_profile -- [l1|l9|border] [tile_shift]
//! [max_candidates] [visit_sweeps]`; with valgrind, `--toggle-collect='*Gibbs*step*'` counts the
//! sampler's instructions only.
use host_sim::eval::sampling::{run_sampler, SamplingConfig, Variant};
use host_sim::sim::{simulate, SimConfig};

fn arg<T: std::str::FromStr>(i: usize, default: T) -> T {
    std::env::args()
        .nth(i)
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn main() -> anyhow::Result<()> {
    let v = match std::env::args().nth(1).as_deref() {
        Some("l1") => Variant::L1,
        Some("l9") => Variant::L9,
        _ => Variant::L9Border,
    };
    let world = host_sim::sim::generate::default_world();
    let run = simulate(&world, &SimConfig::default(), 1)?;
    let cfg = SamplingConfig {
        burn_in: 0,
        sweeps: 10,
        tile_shift: arg(2, 4),
        max_candidates: arg(3, 16),
        visit_sweeps: arg(4, 8),
        block_grid: arg(5, 16),
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
