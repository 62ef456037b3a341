//! Wall time of DIS-medium on the Sintel clean/easy pair (1024x436), run after run (for
//! profiling): `cargo run --release -p flowfilter-flow --example dis_timing` (`N=40` for more runs).

use flowfilter_flow::dis::{Dis, DisParams};
use flowfilter_flow::lk::to_gray;
use flowfilter_flow::{FlowEstimator, sintel};
use std::path::Path;

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/sintel");
    if !root.is_dir() {
        eprintln!("skipping: {} is absent", root.display());
        return;
    }
    let pair = sintel::load(&root.join("clean").join("easy")).expect("sintel pair");
    let (a, b) = (to_gray(&pair.from), to_gray(&pair.to));
    let dis = Dis::new(DisParams::medium()).expect("valid preset");
    for _ in 0..std::env::var("N").ok().and_then(|v| v.parse().ok()).unwrap_or(10) {
        let start = std::time::Instant::now();
        let flow = dis.dense(&a, &b, None).expect("same sizes");
        std::hint::black_box(&flow);
        println!("{:.1} ms", start.elapsed().as_secs_f64() * 1e3);
    }
}
