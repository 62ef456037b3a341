//! Parameter sweep of DIS on the Sintel pairs (development aid):
//! `cargo run --release -p flowfilter-flow --example dis_sweep`.

use flowfilter_flow::dis::{Dis, DisParams};
use flowfilter_flow::lk::to_gray;
use flowfilter_flow::metrics::epe;
use flowfilter_flow::{FlowEstimator, sintel};
use std::path::Path;

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/sintel");
    if !root.is_dir() {
        eprintln!("skipping: {} is absent", root.display());
        return;
    }
    let pairs: Vec<_> = ["clean", "final"]
        .iter()
        .flat_map(|p| ["easy", "medium"].map(|s| (p.to_string(), s)))
        .map(|(p, s)| {
            let pair = sintel::load(&root.join(&p).join(s)).expect("pair");
            (format!("{p}/{s}"), to_gray(&pair.from), to_gray(&pair.to), pair.flow)
        })
        .collect();
    let variants: Vec<(&str, DisParams)> = vec![
        ("medium", DisParams::medium()),
        ("no-meannorm", DisParams { mean_normalization: false, ..DisParams::medium() }),
        ("iters40", DisParams { iterations: 40, ..DisParams::medium() }),
        ("refine10", DisParams { refinement_iterations: 10, ..DisParams::medium() }),
        ("alpha10", DisParams { alpha: 10.0, ..DisParams::medium() }),
        ("stride2", DisParams { patch_stride: 2, ..DisParams::medium() }),
        ("omega1.8", DisParams { omega: 1.8, ..DisParams::medium() }),
        ("om1.9-st4-sor8", DisParams { omega: 1.9, patch_stride: 4, sor_iterations: 8, ..DisParams::medium() }),
    ];
    for (name, p) in variants {
        let d = Dis::new(p).expect("valid");
        let mut line = format!("{name:12}");
        for (label, a, b, gt) in &pairs {
            let t = std::time::Instant::now();
            let f = d.dense(a, b, None).expect("flow");
            let ms = t.elapsed().as_secs_f64() * 1e3;
            line += &format!(" {label} {:.3} ({ms:.0} ms)", epe(&f, gt, None).expect("epe").0);
        }
        println!("{line}");
    }
}
