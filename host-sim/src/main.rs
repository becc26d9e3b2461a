//! `host-sim` command-line interface.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "host-sim",
    version,
    about = "Simulator, evaluation and tools for ogm-core"
)]
struct Cli {
    #[command(subcommand)]
    command: Commands,
}

#[derive(Subcommand)]
enum Commands {
    /// Online insertion throughput of ogm_core::Mapper on CARMEN logs, in the MRPT peer's unit
    /// (cells walked per second) next to cells updated per second.
    BenchInsert(host_sim::eval::bench_insert::BenchInsertArgs),
    /// The main job: map the embedded default world online and score it against ground truth.
    Demo {
        /// Output directory for PNGs and report.json.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
        /// Random seed (world noise, exploration, lidar noise).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Also run the L = 1 and unconditioned L = 9 samplers (slower).
        #[arg(long)]
        all_samplers: bool,
    },
    /// Simulated datasets on ground-truth maps; writes report.json and PR-curve plots.
    EvalSim {
        /// Map files (PNG/PGM/YAML) or directories of them.
        #[arg(long, num_args = 1.., required = true)]
        maps: Vec<PathBuf>,
        /// Simulated datasets per map.
        #[arg(long, default_value_t = 1)]
        runs: u32,
        /// Output directory.
        #[arg(long, default_value = "out/eval-sim")]
        out: PathBuf,
        /// First random seed (run i of map j uses seed + 1000·j + i).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Methods besides traditional OGM: gibbs_l1, gibbs_l1_border, gibbs_l9, gibbs_l9_border,
        /// gibbs_l9_border_rays, gibbs_l9_border_hybrid, gibbs_l9_border_mean, gibbs_l25 and the baselines mh,
        /// mh_heatmap, bp_sum, bp_max, dd (comma-separated), or "none".
        #[arg(
            long,
            default_value = "gibbs_l1,gibbs_l1_border,gibbs_l9,gibbs_l9_border,gibbs_l9_border_rays,gibbs_l9_border_hybrid,gibbs_l9_border_mean,gibbs_l25"
        )]
        methods: String,
        /// Sampler sweeps (map samples) counted after burn-in.
        #[arg(long, default_value_t = 100)]
        sweeps: u32,
        /// Sampler burn-in sweeps.
        #[arg(long, default_value_t = 20)]
        burn_in: u32,
        /// Use the firmware's compile-time buffer sizes (ray store, local list, u8 marginals).
        #[arg(long)]
        firmware_bounds: bool,
        /// Range noise σ (cells) of the simulated lidar, which the methods are told (default:
        /// the paper's 3).
        #[arg(long)]
        sigma_cells: Option<f64>,
    },
    /// The paper's hardware protocol on a real CARMEN log (benchmark, experiments 1-3).
    EvalLog(host_sim::eval::eval_log::EvalLogArgs),
    /// Export a map as ROS map_server PGM + YAML and PNG (from a log, a probability PNG or a
    /// ground-truth map).
    Export(host_sim::export::ExportArgs),
    /// Merali & Barfoot's Fig. 2: the 1-D example's exact posterior next to traditional OGM and
    /// the samplers (SVG plots and exact_1d.json).
    #[command(name = "exact-1d")]
    ExactOneD {
        /// Output directory.
        #[arg(long, default_value = "out/exact-1d")]
        out: PathBuf,
        /// Seed of the readings and the samplers.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Train the data-driven patch prior on the real-map corpus and regenerate its tables.
    TrainPrior {
        /// Training corpus (HouseExpo + ROS maps; never the sim maps).
        #[arg(long, default_value_os_t = host_sim::eval::prior::default_corpus_dir())]
        corpus: PathBuf,
        /// Generated ogm-core table.
        #[arg(long, default_value_os_t = host_sim::eval::prior::default_core_table_path())]
        core_out: PathBuf,
        /// Generated host-side L = 25 table.
        #[arg(long, default_value_os_t = host_sim::eval::prior::default_l25_table_path())]
        l25_out: PathBuf,
        /// Worker threads (the result does not depend on it).
        #[arg(long, default_value_t = host_sim::eval::prior::train::default_threads())]
        threads: usize,
        /// Compare with the committed tables instead of writing them; fail on a difference.
        #[arg(long)]
        check: bool,
        /// Only measure the HouseExpo wall thickness (px) behind the assumed scale.
        #[arg(long)]
        measure_walls: bool,
    },
    /// Run the firmware in QEMU on a simulated run (LD06 bytes + pose frames in, map stream out)
    /// and check its map against ogm-core on the host, cell for cell.
    Firmware(host_sim::firmware::FirmwareArgs),
    /// Watch a robot over its serial link: decode the live map stream, keep the map, show the
    /// link counters, save PNG + ROS map_server PGM/YAML periodically and on Ctrl-C, send host
    /// messages, survive unplug/replug (docs/listen.md).
    Listen(ogm_field::listen::ListenArgs),
    /// Statistics of the compiled patch prior next to the paper's.
    PriorStats {
        /// JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
}

#[allow(clippy::too_many_arguments)]
fn eval_sim(
    maps: &[PathBuf],
    runs: u32,
    out: &std::path::Path,
    seed: u64,
    methods: &str,
    sweeps: u32,
    burn_in: u32,
    firmware_bounds: bool,
    sigma_cells: Option<f64>,
) -> anyhow::Result<()> {
    use host_sim::eval::sampling::{SamplingConfig, Variant};
    let mut variants = Vec::new();
    let mut baselines = Vec::new();
    for m in methods
        .split(',')
        .map(str::trim)
        .filter(|m| !m.is_empty() && *m != "none")
    {
        match Variant::ALL.iter().find(|v| v.name() == m) {
            Some(v) => variants.push(*v),
            None => match host_sim::eval::baselines::Method::from_name(m) {
                Some(b) => baselines.push(b),
                None => anyhow::bail!("--methods: unknown method `{m}` (expected {}, mh, mh_heatmap, bp_sum, bp_max, dd or none)", Variant::ALL.map(|v| v.name()).join(", ")),
            },
        }
    }
    let mut sampling = SamplingConfig {
        sweeps,
        burn_in,
        ..SamplingConfig::default()
    };
    if firmware_bounds {
        sampling = host_sim::eval::eval_sim::with_firmware_bounds(sampling);
    }
    let mut sim = host_sim::sim::SimConfig::default();
    if let Some(s) = sigma_cells {
        anyhow::ensure!(
            s.is_finite() && s > 0.0 && s <= 100.0,
            "--sigma-cells must be a number of cells above 0 and at most 100, not {s}"
        );
        sim.lidar.sigma_cells = s;
        sampling.sigma_cells = s;
    }
    let cfg = host_sim::eval::eval_sim::EvalConfig {
        runs,
        seed,
        variants,
        sim,
        sampling,
        baselines,
        baseline: host_sim::eval::baselines::BaselineConfig {
            model: host_sim::eval::baselines::SensorModel::Gaussian {
                sigma_cells: sampling.sigma_cells,
                outlier_weight: sampling.outlier_weight,
            },
            init_threshold: sampling.init_threshold,
            ..Default::default()
        },
    };
    host_sim::eval::eval_sim::run_sim(maps, out, &cfg)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Commands::Demo {
            out,
            seed,
            all_samplers,
        } => host_sim::eval::demo::run(&out, seed, all_samplers),
        Commands::EvalSim {
            maps,
            runs,
            out,
            seed,
            methods,
            sweeps,
            burn_in,
            firmware_bounds,
            sigma_cells,
        } => eval_sim(
            &maps,
            runs,
            &out,
            seed,
            &methods,
            sweeps,
            burn_in,
            firmware_bounds,
            sigma_cells,
        ),
        Commands::TrainPrior {
            corpus,
            core_out,
            l25_out,
            threads,
            check,
            measure_walls,
        } => {
            if measure_walls {
                host_sim::eval::prior::measure_walls_cmd(&corpus)
            } else {
                host_sim::eval::prior::train_prior_cmd(&corpus, &core_out, &l25_out, threads, check)
            }
        }
        Commands::EvalLog(args) if args.odometry.is_active() => {
            host_sim::eval::eval_odometry::run(&args)
        }
        Commands::EvalLog(args) => host_sim::eval::eval_log::run(&args),
        Commands::Export(args) => host_sim::export::run(&args),
        Commands::ExactOneD { out, seed } => host_sim::eval::baselines::fig2::run(&out, seed),
        Commands::PriorStats { json } => host_sim::eval::prior::prior_stats_cmd(json),
        Commands::Firmware(args) => host_sim::firmware::cli(&args),
        Commands::Listen(args) => ogm_field::listen::cli(&args),
        Commands::BenchInsert(args) => host_sim::eval::bench_insert::cli(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
