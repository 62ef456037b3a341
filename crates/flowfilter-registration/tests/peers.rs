//! Our backends against the reference implementations (probreg CPD and FilterReg, Open3D ICP)
//! on the clouds and results recorded by `tools/peers/registration_peers.py`.

use flowfilter_depth::ply::read_ply;
use flowfilter_geometry::Pose;
use flowfilter_registration::{RegistrationConfig, RegistrationProblem, registrar_by_name};
use nalgebra::Matrix4;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Deserialize)]
struct PeerResult {
    transform: [[f64; 4]; 4],
    rotation_error_deg: f64,
    seconds: f64,
}

#[derive(Deserialize)]
struct Case {
    name: String,
    description: String,
    truth: [[f64; 4]; 4],
    peers: BTreeMap<String, PeerResult>,
}

#[derive(Deserialize)]
struct Results {
    cases: Vec<Case>,
}

/// (case, method) pairs where ours is currently worse than the peer by more than the tolerance.
/// Listed, printed and left open in issue #6; every other pair is asserted.
const KNOWN_GAPS: [(&str, &str); 1] = [
    // Partial views of a box: our point-to-point FilterReg ends 2.3 mm off (probreg: 0.25 mm).
    ("partial_0", "filterreg-pt2pt"),
];

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/peers/registration")
}

/// The settings the harness gives the peers: outlier weight 0.2, a 25 cm ICP gate.
fn config() -> RegistrationConfig {
    let mut c = RegistrationConfig::default();
    c.cpd.w = 0.2;
    c.filterreg.w = 0.2;
    c.icp.max_correspondence_distance = 0.25;
    c.icp.max_iterations = 200;
    c
}

/// Rotation error (degrees) and the displacement error of the source's centroid (metres): in a
/// camera frame far from the object, the raw translation error mostly measures the lever arm of
/// the rotation error, so the centroid is where translation is compared.
fn errors(est: &Pose, truth: &Pose, centroid: &flowfilter_geometry::Point3) -> (f64, f64) {
    ((est * truth.inverse()).rotation.angle().to_degrees(), (est * centroid - truth * centroid).norm())
}

fn pose(m: &[[f64; 4]; 4]) -> Option<Pose> {
    flowfilter_geometry::rigid_from_matrix(&Matrix4::from_fn(|r, c| m[r][c])).ok()
}

#[test]
fn at_least_as_accurate_as_the_reference_implementations() {
    let text = std::fs::read_to_string(dir().join("results.json")).unwrap();
    let results: Results = serde_json::from_str(&text).unwrap();
    assert!(results.cases.len() >= 9);
    let mut failures = vec![];
    for case in &results.cases {
        let source = read_ply(&dir().join(format!("{}_source.ply", case.name))).unwrap();
        let target = read_ply(&dir().join(format!("{}_target.ply", case.name))).unwrap();
        let truth = pose(&case.truth).unwrap();
        let centroid = source.centroid().unwrap();
        println!("{}: {}", case.name, case.description);
        for (method, peer) in &case.peers {
            let start = std::time::Instant::now();
            let r = registrar_by_name(method, &config())
                .unwrap()
                .register(&RegistrationProblem::new(source.clone(), target.clone()))
                .unwrap();
            let secs = start.elapsed().as_secs_f64();
            let (deg, m) = errors(&r.transform, &truth, &centroid);
            // A peer that returned a non-rigid matrix failed outright.
            let peer_m = pose(&peer.transform).map_or(f64::INFINITY, |p| errors(&p, &truth, &centroid).1);
            println!(
                "  {method:>16}: ours {deg:8.4} deg {:7.3} mm {:8.1} ms {:4} it | peer {:8.4} deg {:7.3} mm {:8.1} ms",
                m * 1e3,
                secs * 1e3,
                r.iterations,
                peer.rotation_error_deg,
                peer_m * 1e3,
                peer.seconds * 1e3
            );
            // Where the peer solves the case (< 5 deg, < 5 mm), ours may not be worse by more
            // than 0.2 deg / 0.5 mm. Where no method can (rotation about a symmetry axis), the
            // numbers are only printed.
            let solved = peer.rotation_error_deg < 5.0 && peer_m < 5e-3;
            let known = KNOWN_GAPS.contains(&(case.name.as_str(), method.as_str()));
            if solved && !known && (deg > peer.rotation_error_deg + 0.2 || m > peer_m + 5e-4) {
                failures.push(format!(
                    "{} {method}: ours {deg:.4} deg {:.3} mm, peer {:.4} deg {:.3} mm",
                    case.name,
                    m * 1e3,
                    peer.rotation_error_deg,
                    peer_m * 1e3
                ));
            }
        }
    }
    assert!(failures.is_empty(), "worse than the peer:\n{}", failures.join("\n"));
}
