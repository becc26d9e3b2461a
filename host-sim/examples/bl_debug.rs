use host_sim::baselines::*;
use std::time::Instant;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let map = args
        .get(1)
        .cloned()
        .unwrap_or("../shared/data/maps/sim/cave.png".into());
    let methods: Vec<String> = args
        .get(2)
        .map(|s| s.split(',').map(String::from).collect())
        .unwrap_or(vec!["bp_sum".into()]);
    let world = host_sim::eval::load_eval_world(std::path::Path::new(&map)).unwrap();
    let run = host_sim::sim::simulate(&world, &Default::default(), 1).unwrap();
    let mut cfg = BaselineConfig::default();
    if let Ok(a) = std::env::var("DD_STEP") {
        cfg.dd.step_size = a.parse().unwrap();
    }
    if let Ok(a) = std::env::var("BP_DAMP") {
        cfg.bp.damping = a.parse().unwrap();
    }
    if let Ok(a) = std::env::var("BP_IT") {
        cfg.bp.max_iterations = a.parse().unwrap();
    }
    if let Ok(a) = std::env::var("DD_IT") {
        cfg.dd.max_iterations = a.parse().unwrap();
    }
    if std::env::var("PCSM").is_ok() {
        cfg.model = SensorModel::Pcsm;
    }
    if std::env::var("NOPRIOR").is_ok() {
        cfg.prior_p_occupied = None;
    }
    let t = Instant::now();
    let graph = build_graph(&run.geometry, &run.mapper_config, &run.scans, &cfg).unwrap();
    println!(
        "scans {} factors {} edges {} heat {} build {:.2}s",
        run.scans.len(),
        graph.n_factors(),
        graph.n_edges(),
        graph.heat().len(),
        t.elapsed().as_secs_f64()
    );
    let trad = graph.energy_of_probs(&host_sim::sim::probabilities(&run.map));
    println!("traditional energy {:.1} nll {:.1}", trad.total(), trad.nll);
    let mut pooled = std::collections::BTreeMap::new();
    for m in &methods {
        let o = run_on_graph(Method::from_name(m).unwrap(), &graph, &run.map, &cfg, 1).unwrap();
        println!(
            "{m}: energy {:.1} nll {:.1} secs {:.2} iters {} conv {} lb {:?}",
            o.energy, o.nll, o.seconds, o.iterations, o.converged, o.lower_bound
        );
        let tr: Vec<String> = o
            .trace
            .iter()
            .step_by((o.trace.len() / 12).max(1))
            .map(|(t, e)| format!("{t:.1}:{e:.0}"))
            .collect();
        println!("   trace {}", tr.join(" "));
        pooled.insert(m.clone(), o.probs);
    }
    pooled.insert("traditional".into(), host_sim::sim::probabilities(&run.map));
    let (all, _near) =
        host_sim::eval::evaluate_methods(&world, &[(pooled, run.observed.clone())]).unwrap();
    for (k, s) in all {
        println!(
            "{k}: maxF1 {:.4} thr {:.3}",
            s.max_f1, s.threshold_at_max_f1
        );
    }
}
