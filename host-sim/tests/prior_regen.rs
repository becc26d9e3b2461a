//! The committed prior tables (`ogm-core/src/sampler/prior/table.rs`, `host-sim/src/prior/l25_table.rs`)
//! are exactly what the training corpus `../shared/data/maps/train` generates.
//!
//! Without the shared data this test passes with a loud `SKIPPED` line on stderr (written
//! past the test harness's capture, so it shows in CI logs).

use std::io::Write as _;
use std::path::Path;
use std::time::Instant;

use host_sim::eval::prior::codegen::{emit_core_table, emit_l25_table, PruneParams};
use host_sim::eval::prior::train::{default_threads, train, Corpus};
use host_sim::eval::prior::{default_core_table_path, default_corpus_dir, default_l25_table_path};

fn say(msg: &str) {
    let _ = writeln!(std::io::stderr(), "{msg}");
}

fn first_difference(a: &str, b: &str) -> String {
    for (i, (x, y)) in a.lines().zip(b.lines()).enumerate() {
        if x != y {
            return format!("line {}:\n  committed: {x}\n  generated: {y}", i + 1);
        }
    }
    format!(
        "lengths differ: committed {} lines, generated {} lines",
        a.lines().count(),
        b.lines().count()
    )
}

fn check(path: &Path, generated: &str) -> Result<(), String> {
    let committed = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    if committed == generated {
        Ok(())
    } else {
        Err(format!(
            "{} is not what the corpus generates (regenerate with `cargo run --release -p host-sim \
             -- train-prior` and commit): {}",
            path.display(),
            first_difference(&committed, generated)
        ))
    }
}

#[test]
fn committed_tables_regenerate_from_the_corpus() {
    let root = default_corpus_dir();
    if !root.is_dir() {
        say(&format!(
            "SKIPPED: ../shared/data not found ({} is absent): the committed prior tables were \
             NOT checked against their training corpus",
            root.display()
        ));
        return;
    }
    let t0 = Instant::now();
    let corpus = Corpus::scan(&root).expect("scanning the corpus");
    let training = train(&corpus, default_threads()).expect("training");
    let core = emit_core_table(&training, &PruneParams::default()).expect("codegen");
    let l25 = emit_l25_table(&training);
    say(&format!(
        "prior regeneration: {} maps, {} windows, {:.1} s",
        corpus.maps.len(),
        training.windows(),
        t0.elapsed().as_secs_f64()
    ));
    let errors: Vec<String> = [
        check(&default_core_table_path(), &core),
        check(&default_l25_table_path(), &l25),
    ]
    .into_iter()
    .filter_map(Result::err)
    .collect();
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}
