//! Score an estimated relative pose against the truth with every metric of the benchmark.
//! Run: `cargo run -p flowfilter-eval --example score_estimate`.

use flowfilter_eval::PoseErrors;
use flowfilter_geometry::{Point3, Pose, Vector3};

fn main() {
    let truth = Pose::new(Vector3::new(0.01, 0.0, 0.002), Vector3::new(0.0, 0.0, 15f64.to_radians()));
    let estimate = Pose::new(Vector3::new(0.011, 0.001, 0.002), Vector3::new(0.002, 0.0, 14.2f64.to_radians()));
    // ADD-S needs the model's points: a ring of radius 4 cm.
    let model: Vec<Point3> = (0..64)
        .map(|i| i as f64 / 64.0 * std::f64::consts::TAU)
        .map(|a| Point3::new(0.04 * a.cos(), 0.04 * a.sin(), 0.7))
        .collect();
    let e = PoseErrors::new(&estimate, &truth, Some(&model));
    println!("{e:#?}");
}
