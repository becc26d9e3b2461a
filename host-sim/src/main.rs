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
    /// The main job: map the embedded default world online and score it against ground truth.
    Demo {
        /// Output directory for PNGs and report.json.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
        /// Random seed (world noise, exploration, lidar noise).
        #[arg(long, default_value_t = 1)]
        seed: u64,
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
    },
    /// Train the data-driven patch prior on the real-map corpus and regenerate its tables.
    TrainPrior {
        /// Training corpus (HouseExpo + ROS maps; never the sim maps).
        #[arg(long, default_value_os_t = host_sim::prior::default_corpus_dir())]
        corpus: PathBuf,
        /// Generated ogm-core table.
        #[arg(long, default_value_os_t = host_sim::prior::default_core_table_path())]
        core_out: PathBuf,
        /// Generated host-side L = 25 table.
        #[arg(long, default_value_os_t = host_sim::prior::default_l25_table_path())]
        l25_out: PathBuf,
        /// Worker threads (the result does not depend on it).
        #[arg(long, default_value_t = host_sim::prior::train::default_threads())]
        threads: usize,
        /// Compare with the committed tables instead of writing them; fail on a difference.
        #[arg(long)]
        check: bool,
        /// Only measure the HouseExpo wall thickness (px) behind the assumed scale.
        #[arg(long)]
        measure_walls: bool,
    },
    /// Statistics of the compiled patch prior next to the paper's.
    PriorStats {
        /// JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Commands::Demo { out, seed } => host_sim::demo::run(&out, seed),
        Commands::EvalSim {
            maps,
            runs,
            out,
            seed,
        } => host_sim::eval::run_sim(&maps, runs, &out, seed),
        Commands::TrainPrior {
            corpus,
            core_out,
            l25_out,
            threads,
            check,
            measure_walls,
        } => {
            if measure_walls {
                host_sim::prior::measure_walls_cmd(&corpus)
            } else {
                host_sim::prior::train_prior_cmd(&corpus, &core_out, &l25_out, threads, check)
            }
        }
        Commands::PriorStats { json } => host_sim::prior::prior_stats_cmd(json),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
