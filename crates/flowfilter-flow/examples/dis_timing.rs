//! Wall time of DIS-medium on one Sintel pair (1024x436), run after run: for profiling, and for
//! `tools/peers/flow_dis_ratio.py`, which alternates it with OpenCV's DIS to time both in the
//! same minutes.
//!
//! `cargo run --release -p flowfilter-flow --example dis_timing [-- PASS/SCENE]` (default
//! `clean/easy`); `N=40` for more runs, `GRADIENTS=central` for the central-difference patch
//! search (default: the preset's `opencv_sobel`).

use flowfilter_flow::dis::{Dis, DisParams, SearchGradients};
use flowfilter_flow::lk::to_gray;
use flowfilter_flow::{FlowEstimator, sintel};
use std::path::Path;

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/sintel");
    if !root.is_dir() {
        eprintln!("skipping: {} is absent", root.display());
        return;
    }
    let case = std::env::args().nth(1).unwrap_or_else(|| "clean/easy".into());
    let pair = sintel::load(&root.join(&case)).expect("sintel pair");
    let (a, b) = (to_gray(&pair.from), to_gray(&pair.to));
    let mut params = DisParams::medium();
    match std::env::var("GRADIENTS").as_deref() {
        Ok("central") => params.search_gradients = SearchGradients::Central,
        Ok("opencv_sobel") | Err(_) => params.search_gradients = SearchGradients::OpencvSobel,
        Ok(other) => panic!("GRADIENTS must be central or opencv_sobel, found {other}"),
    }
    let dis = Dis::new(params).expect("valid preset");
    for _ in 0..std::env::var("N").ok().and_then(|v| v.parse().ok()).unwrap_or(10) {
        let start = std::time::Instant::now();
        let flow = dis.dense(&a, &b, None).expect("same sizes");
        std::hint::black_box(&flow);
        println!("{:.2} ms", start.elapsed().as_secs_f64() * 1e3);
    }
}
