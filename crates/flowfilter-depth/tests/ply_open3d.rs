//! PLY written by us reads identically in Open3D, and PLY written by Open3D reads identically
//! here (fixtures recorded by `tools/peers/ply_open3d.py`).

use flowfilter_depth::ply::read_ply;
use flowfilter_geometry::PointCloud;
use serde::Deserialize;
use std::path::{Path, PathBuf};

#[derive(Deserialize)]
struct Seen {
    points: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    colors_u8: Vec<[u8; 3]>,
}

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
}

fn assert_same(cloud: &PointCloud, seen: &Seen, what: &str) {
    assert_eq!(cloud.len(), seen.points.len(), "{what}: point count");
    let normals = cloud.normals.as_ref().expect("normals");
    let colors = cloud.colors.as_ref().expect("colours");
    for i in 0..cloud.len() {
        let (p, n) = (cloud.points[i], normals[i]);
        assert_eq!([p.x, p.y, p.z], seen.points[i], "{what}: point {i}");
        assert_eq!([n.x, n.y, n.z], seen.normals[i], "{what}: normal {i}");
        assert_eq!(colors[i], seen.colors_u8[i], "{what}: colour {i}");
    }
}

#[test]
fn open3d_reads_our_ply_identically() {
    #[derive(Deserialize)]
    struct Read {
        ascii: Seen,
        binary: Seen,
    }
    let text = std::fs::read_to_string(fixtures().join("peers/open3d_read_ours.json")).unwrap();
    let read: Read = serde_json::from_str(&text).unwrap();
    for (fmt, seen) in [("ascii", &read.ascii), ("binary", &read.binary)] {
        let ours = read_ply(&fixtures().join(format!("ply/ours_{fmt}.ply"))).unwrap();
        assert_same(&ours, seen, &format!("ours_{fmt}.ply as Open3D read it"));
    }
}

#[test]
fn we_read_open3d_ply_identically() {
    let text = std::fs::read_to_string(fixtures().join("peers/open3d_written.json")).unwrap();
    let written: Seen = serde_json::from_str(&text).unwrap();
    for fmt in ["ascii", "binary"] {
        let cloud = read_ply(&fixtures().join(format!("ply/open3d_{fmt}.ply"))).unwrap();
        if fmt == "binary" {
            assert_same(&cloud, &written, "open3d_binary.ply");
        } else {
            // Open3D's ASCII writer prints a limited number of digits: equal to that precision.
            assert_eq!(cloud.len(), written.points.len());
            for (p, q) in cloud.points.iter().zip(&written.points) {
                assert!((p.x - q[0]).abs() < 1e-6 && (p.y - q[1]).abs() < 1e-6 && (p.z - q[2]).abs() < 1e-6);
            }
            assert_eq!(cloud.colors.as_ref().unwrap(), &written.colors_u8);
        }
    }
}
