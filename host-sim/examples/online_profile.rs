//! Profiling aid: the firmware's per-scan loop on the host (firmware sizes, `u8` counts), for
//! callgrind: `valgrind --tool=callgrind --toggle-collect='*Gibbs*step*'
//! target/release/examples/online_profile [UPDATES] [data] [estimator]`.
use host_sim::firmware::{firmware_world, run_config, FirmwareArgs, FIRMWARE_SIZES};
use host_sim::sim::{simulate, SimConfig};
use ogm_core::session::{Owned, Session};

fn main() -> anyhow::Result<()> {
    let updates: u32 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(13_000);
    let mut args = FirmwareArgs::default();
    if let Some(d) = std::env::args().nth(2) {
        args.sampler.data =
            Some(host_sim::firmware::parse_data_term(&d).map_err(anyhow::Error::msg)?);
    }
    if let Some(e) = std::env::args().nth(3) {
        args.sampler.estimator =
            Some(host_sim::firmware::parse_estimator(&e).map_err(anyhow::Error::msg)?);
    }
    let world = firmware_world(&args)?;
    let sim = simulate(&world, &SimConfig::default(), 1)?;
    let config = run_config(&world, &args, sim.mapper_config.max_range_mm);
    let mut r = Session::new(config, Owned::<u8>::buffers(&FIRMWARE_SIZES))?;
    for s in &sim.scans {
        r.insert(&s.pose, &s.beams)?;
        r.step(updates);
    }
    println!("{:?}", r.sampler_report());
    Ok(())
}
