//! Our projection and undistortion agree with OpenCV's `projectPoints` / `undistortPoints`,
//! recorded by `tools/peers/camera_opencv.py` in `fixtures/peers/camera_opencv.json`.

use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, Pixel};
use flowfilter_geometry::Point3;
use nalgebra::Matrix3;
use serde::Deserialize;

#[derive(Deserialize)]
struct Reference {
    #[serde(rename = "K")]
    k: [[f64; 3]; 3],
    dist: Vec<f64>,
    points: Vec<[f64; 3]>,
    projected: Vec<[f64; 2]>,
    pixels: Vec<[f64; 2]>,
    undistorted: Vec<[f64; 2]>,
}

fn load() -> (CameraModel, Reference) {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../fixtures/peers/camera_opencv.json");
    let text = std::fs::read_to_string(path).expect("fixture fixtures/peers/camera_opencv.json is committed");
    let r: Reference = serde_json::from_str(&text).expect("fixture parses");
    let k = Matrix3::from_fn(|i, j| r.k[i][j]);
    let cam = CameraModel::new(
        Intrinsics::from_matrix(&k).unwrap(),
        Distortion::from_slice(&r.dist).unwrap(),
        ImageSize::new(1280, 1024).unwrap(),
    );
    (cam, r)
}

#[test]
fn projection_matches_opencv() {
    let (cam, r) = load();
    assert!(!r.points.is_empty());
    for (p, expected) in r.points.iter().zip(&r.projected) {
        let q = cam.project(&Point3::new(p[0], p[1], p[2])).unwrap();
        let err = (q - Pixel::new(expected[0], expected[1])).norm();
        assert!(err < 1e-6, "projectPoints differs by {err} px at {p:?}");
    }
}

#[test]
fn undistortion_matches_opencv() {
    let (cam, r) = load();
    for (p, expected) in r.pixels.iter().zip(&r.undistorted) {
        let q = cam.undistort_pixel(&Pixel::new(p[0], p[1])).unwrap();
        let err = (q - Pixel::new(expected[0], expected[1])).norm();
        assert!(err < 1e-4, "undistortPoints differs by {err} px at {p:?}");
    }
}
