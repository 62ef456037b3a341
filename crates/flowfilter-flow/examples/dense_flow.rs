//! Dense optical flow of two images with DIS, written as Middlebury `.flo` and a colour-wheel
//! PNG. Run: `cargo run --release -p flowfilter-flow --example dense_flow -- A.png B.png OUT`
//! (writes OUT.flo and OUT.png; try the Sintel pairs of `../shared/data/sintel`).

use flowfilter_flow::dis::DisParams;
use flowfilter_flow::lk::to_gray;
use flowfilter_flow::{LucasKanade, flo, flow_estimator_by_name, viz};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [a, b, out] = args.as_slice() else { return Err("usage: dense_flow A.png B.png OUT".into()) };
    let (from, to) = (to_gray(&image::open(a)?.to_rgb8()), to_gray(&image::open(b)?.to_rgb8()));
    let estimator = flow_estimator_by_name("dis", &LucasKanade::default(), &DisParams::medium())?;
    let started = std::time::Instant::now();
    let field = estimator.dense(&from, &to, None)?;
    println!("{}x{} flow in {:.1} ms", field.width(), field.height(), started.elapsed().as_secs_f64() * 1e3);
    flo::write(&field, std::path::Path::new(&format!("{out}.flo")))?;
    viz::colorize(&field, None).save(format!("{out}.png"))?;
    Ok(())
}
