//! Time per map sample (K/L patch updates) of each Gibbs variant at K = 65,536 cells on a
//! realistic dataset: a 256 × 256-cell (12.8 m) building from the world generator, explored by
//! the simulated robot (360-beam lidar, F = 75 cells, σ = 3 cells), burnt in for 10 sweeps
//! before timing. `cargo bench -p host-sim --bench sampler`.

use criterion::{criterion_group, criterion_main, Criterion};
use host_sim::eval::sampling::{SamplingConfig, Variant};
use host_sim::sim::generate::{generate, GenParams};
use host_sim::sim::{simulate, SimConfig};

fn bench(c: &mut Criterion) {
    let params = GenParams {
        width: 256,
        height: 256,
        ..GenParams::default()
    };
    let world = generate(&params, 3);
    let run = simulate(&world, &SimConfig::default(), 3).expect("simulation");
    assert_eq!(run.geometry.len(), 65_536);
    let mut group = c.benchmark_group("map_sample_65536");
    group.sample_size(10);
    for v in Variant::ALL {
        let cfg = SamplingConfig::default();
        let mut s = host_sim::eval::sampling::Prepared::new(
            run.geometry,
            &run.mapper_config,
            &run.scans,
            &run.map,
            v,
            &cfg,
            3,
        )
        .expect("sampler");
        s.sweeps(10); // burn-in
        group.bench_function(v.name(), |b| b.iter(|| s.sweeps(1)));
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
