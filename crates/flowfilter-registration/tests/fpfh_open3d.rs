//! Our FPFH descriptors and their mutual matches against Open3D 0.20's on the same clouds,
//! recorded by `tools/peers/fpfh_open3d.py` in `fixtures/peers/fpfh_open3d.json`.

use flowfilter_registration::global::{GlobalConfig, fpfh_features, mutual_matches, register_by_features};
use flowfilter_registration::{Point3, PointCloud, Pose, Vector3};
use serde::Deserialize;

#[derive(Deserialize)]
struct Fixture {
    radius: f64,
    max_nn: usize,
    points: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    moved_points: Vec<[f64; 3]>,
    moved_normals: Vec<[f64; 3]>,
    rotation: [[f64; 3]; 3],
    translation: [f64; 3],
    features: Vec<Vec<f32>>,
    moved_features: Vec<Vec<f32>>,
    mutual_matches: Vec<[usize; 2]>,
}

fn fixture() -> Fixture {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../fixtures/peers/fpfh_open3d.json");
    let text = std::fs::read_to_string(path).expect("fixture fixtures/peers/fpfh_open3d.json is committed");
    serde_json::from_str(&text).expect("the fixture parses")
}

fn cloud(points: &[[f64; 3]], normals: &[[f64; 3]]) -> PointCloud {
    PointCloud {
        points: points.iter().map(|p| Point3::new(p[0], p[1], p[2])).collect(),
        normals: Some(normals.iter().map(|n| Vector3::new(n[0], n[1], n[2])).collect()),
        ..Default::default()
    }
}

#[test]
fn our_fpfh_descriptors_are_open3ds() {
    let f = fixture();
    for (points, normals, want) in
        [(&f.points, &f.normals, &f.features), (&f.moved_points, &f.moved_normals, &f.moved_features)]
    {
        let ours = fpfh_features(&cloud(points, normals), f.radius, f.max_nn).unwrap();
        assert_eq!(ours.len(), want.len());
        let worst =
            ours.iter().zip(want).flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs())).fold(0.0f32, f32::max);
        // Open3D's values are recorded to 4 decimals of bins that reach about 200.
        assert!(worst < 2e-3, "largest difference of a bin: {worst}");
    }
}

#[test]
fn our_mutual_matches_are_open3ds() {
    let f = fixture();
    let a = fpfh_features(&cloud(&f.points, &f.normals), f.radius, f.max_nn).unwrap();
    let b = fpfh_features(&cloud(&f.moved_points, &f.moved_normals), f.radius, f.max_nn).unwrap();
    let ours: Vec<[usize; 2]> = mutual_matches(&a, &b).into_iter().map(|(i, j)| [i, j]).collect();
    assert_eq!(ours, f.mutual_matches);
}

#[test]
fn the_global_registration_finds_the_recorded_motion() {
    let f = fixture();
    let rotation = nalgebra::Matrix3::from_fn(|r, c| f.rotation[r][c]);
    let truth = Pose::from_parts(
        nalgebra::Translation3::new(f.translation[0], f.translation[1], f.translation[2]),
        nalgebra::UnitQuaternion::from_matrix(&rotation),
    );
    let cfg = GlobalConfig { feature_radius_m: f.radius, max_distance_m: 0.004, ..GlobalConfig::default() };
    let found =
        register_by_features(&cloud(&f.points, &f.normals), &cloud(&f.moved_points, &f.moved_normals), &cfg).unwrap();
    let error = (found.pose.inverse() * truth).rotation.angle().to_degrees();
    assert!(error < 1.0, "{error} deg off the 35-deg motion ({} of {} matches agree)", found.inliers, found.matches);
}
