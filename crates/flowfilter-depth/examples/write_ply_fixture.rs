//! Writes `fixtures/ply/ours_{ascii,binary}.ply` (a deterministic coloured cloud with normals),
//! which `tools/peers/ply_open3d.py` reads back with Open3D.
//! Run: `cargo run -p flowfilter-depth --example write_ply_fixture`.

use flowfilter_depth::ply::{PlyFormat, write_ply};
use flowfilter_geometry::{Point3, PointCloud, Vector3};
use std::path::Path;

fn main() {
    let points: Vec<Point3> = (0..200)
        .map(|i| {
            let t = i as f64 * 0.173;
            Point3::new(0.1 * t.cos(), 0.05 * (2.0 * t).sin(), 0.7 + 0.001 * i as f64)
        })
        .collect();
    let normals = points.iter().map(|p| Vector3::new(p.x, p.y, -0.3).normalize()).collect();
    let colors = (0..200).map(|i| [(i * 7 % 256) as u8, (i * 13 % 256) as u8, (255 - i) as u8]).collect();
    let cloud = PointCloud { points, normals: Some(normals), colors: Some(colors), pixels: None };
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/ply");
    std::fs::create_dir_all(&dir).unwrap();
    write_ply(&cloud, &dir.join("ours_ascii.ply"), PlyFormat::Ascii).unwrap();
    write_ply(&cloud, &dir.join("ours_binary.ply"), PlyFormat::BinaryLittleEndian).unwrap();
    println!("wrote {}", dir.display());
}
