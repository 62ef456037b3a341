//! Flow Filter's FilterReg runs on a scene (`FlowFilterConfig::scene_points`): point-to-plane
//! above the threshold, the configured objective below it.

use flowfilter_geometry::{Point3, PointCloud, Pose, Vector3};
use flowfilter_registration::{
    FilterReg, FilterRegConfig, FilterRegVariant, FlowFilter, FlowFilterConfig, Registrar, RegistrationProblem,
};

/// A wavy surface 0.6 m in front of the camera, `side x side` points over 40 x 30 cm, with its
/// normals (facing the camera).
fn surface(side: usize) -> PointCloud {
    let height = |x: f64, y: f64| 0.6 + 0.02 * (8.0 * x).sin() * (6.0 * y).cos();
    let mut cloud = PointCloud::from_points(vec![]);
    let mut normals = vec![];
    for i in 0..side {
        for j in 0..side {
            let (x, y) = (0.4 * i as f64 / side as f64 - 0.2, 0.3 * j as f64 / side as f64 - 0.15);
            let (dx, dy) = (0.16 * (8.0 * x).cos() * (6.0 * y).cos(), -0.12 * (8.0 * x).sin() * (6.0 * y).sin());
            cloud.points.push(Point3::new(x, y, height(x, y)));
            normals.push(Vector3::new(dx, dy, -1.0).normalize());
        }
    }
    cloud.normals = Some(normals);
    cloud
}

/// The pair: the surface and the same surface moved by 3 deg and 1 cm.
fn problem(side: usize) -> RegistrationProblem {
    let source = surface(side);
    let motion = Pose::new(Vector3::new(0.01, -0.004, 0.002), Vector3::new(0.02, 0.05, 0.01));
    RegistrationProblem::new(source.clone(), source.transformed(&motion))
}

/// FilterReg alone with `variant`, the rest as Flow Filter's geometric runs configure it.
fn filterreg(variant: FilterRegVariant, p: &RegistrationProblem) -> Pose {
    let cfg = FilterRegConfig { variant, correspondence_weight: 0.0, ..FilterRegConfig::default() };
    FilterReg::new(cfg).unwrap().register(&p.geometry_only()).unwrap().transform
}

#[test]
fn a_scene_is_registered_point_to_plane_and_an_object_as_configured() {
    let flow_filter = FlowFilter::new(FlowFilterConfig { scene_points: 2000, ..FlowFilterConfig::default() }).unwrap();
    // 2500 points: a scene for this threshold.
    let scene = problem(50);
    let prior = flow_filter.prior(&scene).unwrap().expect("a prior").transform;
    assert_eq!(prior, filterreg(FilterRegVariant::PointToPlane, &scene));
    assert_ne!(prior, filterreg(FilterRegVariant::PointToPoint, &scene));
    // 1600 points: an object, registered with the configured objective (point-to-point).
    let object = problem(40);
    let prior = flow_filter.prior(&object).unwrap().expect("a prior").transform;
    assert_eq!(prior, filterreg(FilterRegVariant::PointToPoint, &object));
    // The same 1600 points standing for 2500 (thinned by a budget): a scene.
    let thinned = RegistrationProblem { source_points: Some(2500), ..problem(40) };
    let prior = flow_filter.prior(&thinned).unwrap().expect("a prior").transform;
    assert_eq!(prior, filterreg(FilterRegVariant::PointToPlane, &thinned));
    // 0 turns the rule off.
    let off = FlowFilter::new(FlowFilterConfig { scene_points: 0, ..FlowFilterConfig::default() }).unwrap();
    assert_eq!(off.prior(&scene).unwrap().unwrap().transform, filterreg(FilterRegVariant::PointToPoint, &scene));
}
