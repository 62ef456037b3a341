//! Recover a rigid motion from noisy point pairs with weighted Kabsch, one pair an outlier
//! weighted down. Run: `cargo run -p flowfilter-geometry --example kabsch_from_pairs`.

use flowfilter_geometry::{Point3, Pose, Vector3, rotation_angle_deg, weighted_kabsch};

fn main() {
    let truth = Pose::new(Vector3::new(0.02, -0.01, 0.005), Vector3::new(0.0, 0.35, 0.05));
    let source: Vec<Point3> = (0..30)
        .map(|i| {
            let a = i as f64 * 0.7;
            Point3::new(0.1 * a.cos(), 0.08 * a.sin(), 0.6 + 0.002 * i as f64)
        })
        .collect();
    let mut target: Vec<Point3> = source
        .iter()
        .enumerate()
        .map(|(i, p)| truth * p + Vector3::new(1e-4 * (i as f64).sin(), 1e-4 * (i as f64).cos(), 0.0))
        .collect();
    target[7] += Vector3::new(0.05, 0.0, 0.0); // a wrong pair
    let mut weights = vec![1.0; source.len()];
    weights[7] = 0.0;
    let estimate = weighted_kabsch(&source, &target, Some(&weights)).expect("three or more pairs");
    let error = rotation_angle_deg(&(estimate.inverse() * truth));
    println!("true rotation {:.3} deg; estimate off by {error:.4} deg", rotation_angle_deg(&truth));
}
