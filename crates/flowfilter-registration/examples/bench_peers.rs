//! Times our backends on the clouds written by `tools/peers/registration_peers.py --bench DIR`
//! and prints them beside the peers' times and errors recorded in `DIR/peers.json`.
//! Run: `cargo run --release -p flowfilter-registration --example bench_peers -- DIR`
//! `[METHODS] [REPEAT]` (set `RAYON_NUM_THREADS=1` or `2` for the thread count; METHODS: a
//! comma-separated subset of `cpd,filterreg-pt2pt,filterreg-pt2pl,icp-pt2pt,icp-pt2pl`; REPEAT:
//! time each run this many times and keep the fastest, as `registration_peers.py --repeat` does).

use flowfilter_depth::ply::read_ply;
use flowfilter_registration::{RegistrationConfig, RegistrationProblem, registrar_by_name};
use nalgebra::Matrix4;
use std::path::PathBuf;

fn main() {
    let dir = PathBuf::from(std::env::args().nth(1).expect("usage: bench_peers DIR"));
    // Optional second argument: a comma-separated subset of the methods.
    let methods = std::env::args()
        .nth(2)
        .unwrap_or_else(|| "cpd,filterreg-pt2pt,filterreg-pt2pl,icp-pt2pt,icp-pt2pl".to_string());
    let repeat: usize = std::env::args().nth(3).map_or(1, |r| r.parse().expect("REPEAT: a positive integer")).max(1);
    let peers: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("peers.json")).unwrap()).unwrap();
    let mut config = RegistrationConfig::default();
    config.cpd.w = 0.2;
    config.filterreg.w = 0.2;
    config.icp.max_correspondence_distance = 0.25;
    config.icp.max_iterations = 200;
    // Open3D's stopping rule exactly (fitness and RMSE changes below 1e-6): the same iterations.
    config.icp.min_update = 0.0;
    println!("threads: {}", rayon::current_num_threads());
    println!("| points | method | ours (s) | peer (s) | speed-up | ours (deg) | peer (deg) | our iterations |");
    println!("| --- | --- | --- | --- | --- | --- | --- | --- |");
    for row in peers.as_array().unwrap() {
        let n = row["n"].as_u64().unwrap();
        let source = read_ply(&dir.join(format!("n{n}_source.ply"))).unwrap();
        let target = read_ply(&dir.join(format!("n{n}_target.ply"))).unwrap();
        let t = &row["truth"];
        let truth =
            flowfilter_geometry::rigid_from_matrix(&Matrix4::from_fn(|r, c| t[r][c].as_f64().unwrap())).unwrap();
        for method in methods.split(',') {
            let reg = registrar_by_name(method, &config).unwrap();
            let problem = RegistrationProblem::new(source.clone(), target.clone());
            let (mut r, mut secs) = (None, f64::INFINITY);
            for _ in 0..repeat {
                let start = std::time::Instant::now();
                r = Some(reg.register(&problem).unwrap());
                secs = secs.min(start.elapsed().as_secs_f64());
            }
            let r = r.expect("at least one run");
            let deg = (r.transform * truth.inverse()).rotation.angle().to_degrees();
            let peer = &row["peers"][method];
            match (peer["seconds"].as_f64(), peer["rotation_error_deg"].as_f64()) {
                (Some(ps), Some(pd)) => {
                    println!(
                        "| {n} | {method} | {secs:.4} | {ps:.3} | {:.1}x | {deg:.4} | {pd:.4} | {} |",
                        ps / secs,
                        r.iterations
                    )
                }
                _ => println!("| {n} | {method} | {secs:.4} | not run | - | {deg:.4} | - | {} |", r.iterations),
            }
        }
    }
}
