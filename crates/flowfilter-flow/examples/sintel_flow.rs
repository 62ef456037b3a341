//! EPE and time of the dense estimators on the Sintel pairs of `../shared/data/sintel`:
//! `cargo run --release -p flowfilter-flow [--features onnx] --example sintel_flow [-- REPEATS]`
//! (with `onnx`: also our network, crates/flowfilter-flow/models/ffnet.onnx).

use flowfilter_flow::dis::{Dis, DisParams, SearchGradients};
use flowfilter_flow::lk::to_gray;
use flowfilter_flow::metrics::epe;
use flowfilter_flow::{FlowEstimator, LucasKanade, sintel};
use std::path::Path;
use std::time::Instant;

fn main() {
    let repeats: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(5);
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/sintel");
    if !root.is_dir() {
        eprintln!("skipping: {} is absent", root.display());
        return;
    }
    let estimators: Vec<(&str, Box<dyn FlowEstimator>)> = vec![
        ("dis-fast", Box::new(Dis::new(DisParams::fast()).expect("valid"))),
        ("dis-medium", Box::new(Dis::new(DisParams::medium()).expect("valid"))),
        (
            "dis-medium (central)",
            Box::new(
                Dis::new(DisParams { search_gradients: SearchGradients::Central, ..DisParams::medium() })
                    .expect("valid"),
            ),
        ),
        ("lk-dense", Box::new(LucasKanade::default())),
        #[cfg(feature = "onnx")]
        ("net (ffnet)", Box::new(flowfilter_flow::net::ffnet().expect("shipped network"))),
    ];
    println!("| pass | scene | method | EPE all | EPE non-occluded | median ms |");
    println!("| --- | --- | --- | --- | --- | --- |");
    for pass in ["clean", "final"] {
        for scene in ["easy", "medium"] {
            let pair = sintel::load(&root.join(pass).join(scene)).expect("sintel pair");
            let (a, b) = (to_gray(&pair.from), to_gray(&pair.to));
            for (name, est) in &estimators {
                let mut times = vec![];
                let mut field = None;
                for _ in 0..repeats {
                    let t = Instant::now();
                    field = Some(est.dense(&a, &b, None).expect("flow"));
                    times.push(t.elapsed().as_secs_f64() * 1e3);
                }
                times.sort_by(f64::total_cmp);
                let f = field.expect("ran");
                let all = epe(&f, &pair.flow, None).map_or(f64::NAN, |e| e.0);
                let noc = epe(&f, &pair.flow, Some(&pair.non_occluded)).map_or(f64::NAN, |e| e.0);
                println!("| {pass} | {scene} | {name} | {all:.3} | {noc:.3} | {:.1} |", times[times.len() / 2]);
            }
            // Sparse LK on OpenCV's grid (16 px step, offset 8), as in fixtures/peers/flow_opencv.json.
            let grid: Vec<[usize; 2]> = (0..)
                .map(|j| 8 + 16 * j)
                .take_while(|y| *y < a.height() - 8)
                .flat_map(|y| (0..).map(|i| 8 + 16 * i).take_while(|x| *x < a.width() - 8).map(move |x| [x, y]))
                .collect();
            let pts: Vec<[f32; 2]> = grid.iter().map(|&[x, y]| [x as f32, y as f32]).collect();
            let lk = LucasKanade::default();
            let mut times = vec![];
            let mut tracked = vec![];
            for _ in 0..repeats {
                let t = Instant::now();
                tracked = lk.sparse(&a, &b, &pts, None).expect("lk");
                times.push(t.elapsed().as_secs_f64() * 1e3);
            }
            times.sort_by(f64::total_cmp);
            let rows: Vec<([usize; 2], Option<[f32; 2]>)> = grid.iter().copied().zip(tracked).collect();
            let (e, n) = flowfilter_flow::metrics::epe_at_points(&rows, &pair.flow).expect("points");
            println!(
                "| {pass} | {scene} | lk-sparse ({n}/{} points) | {e:.3} | - | {:.1} |",
                grid.len(),
                times[times.len() / 2]
            );
        }
    }
}
