//! A start for a local registration found without one: both clouds thinned to a budget, given
//! normals, registered globally by their FPFH matches ([`flowfilter_registration::global`]) and
//! refined by point-to-plane ICP (Open3D's global registration tutorial, end to end). The
//! pipeline's geometric guide (`[flow.wide.geometry]`) and `flowfilter register --global` use it.

use crate::config::GeometryGuideConfig;
use flowfilter_depth::cloud::{knn_normals, thin_to_budget, voxel_downsample};
use flowfilter_geometry::{Point3, PointCloud, Pose};
use flowfilter_registration::global::{GlobalConfig, register_by_features};
use flowfilter_registration::{Icp, IcpConfig, IcpVariant, Registrar, RegistrationProblem};

/// What [`global_start`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct GlobalStart {
    /// The motion `T` with `target ~ T * source`, refined by ICP.
    pub pose: Pose,
    /// The voxel both clouds were thinned to (metres).
    pub voxel_m: f64,
    /// Descriptor matches that agree with the RANSAC's motion...
    pub inliers: usize,
    /// ...of this many mutual matches.
    pub matches: usize,
}

/// ICP iterations refining the global registration.
const ICP_ITERATIONS: usize = 30;

/// The motion of `source` onto `target` from nowhere (module documentation): the source is
/// thinned to at most `cfg.max_points` points from the voxel `cfg.min_voxel_m` up, the target to
/// the same voxel (and the same budget); descriptors over `cfg.feature_radius_voxels` voxels,
/// agreement within `cfg.match_distance_voxels`. `None` when no motion gathers
/// `cfg.min_inliers` matches.
///
/// ```
/// use flowfilter_pipeline::{GeometryGuideConfig, Point3, PointCloud, Pose, global_start};
///
/// // A bumpy sheet and the same sheet turned by 40 degrees about the vertical.
/// let points: Vec<Point3> = (0..6400)
///     .map(|i| {
///         let (x, y) = ((i % 80) as f64 * 0.0025, (i / 80) as f64 * 0.0025);
///         Point3::new(x, y, 0.6 + 0.01 * (x * 40.0).sin() * (y * 30.0).cos())
///     })
///     .collect();
/// let truth = Pose::new(nalgebra::Vector3::new(0.05, 0.0, 0.02), nalgebra::Vector3::new(0.0, 40f64.to_radians(), 0.0));
/// let source = PointCloud::from_points(points.clone());
/// let target = PointCloud::from_points(points.iter().map(|p| truth * p).collect());
/// let found = global_start(&source, &target, &GeometryGuideConfig::default()).expect("matched");
/// assert!((found.pose.inverse() * truth).rotation.angle().to_degrees() < 1.0);
/// ```
pub fn global_start(source: &PointCloud, target: &PointCloud, cfg: &GeometryGuideConfig) -> Option<GlobalStart> {
    let (source, voxel) = thin_to_budget(source.clone(), cfg.min_voxel_m, cfg.max_points);
    let (target, _) = thin_to_budget(voxel_downsample(target, voxel), voxel, cfg.max_points);
    let (source, target) = (with_normals(source, cfg), with_normals(target, cfg));
    let global = GlobalConfig {
        feature_radius_m: cfg.feature_radius_voxels * voxel,
        max_distance_m: cfg.match_distance_voxels * voxel,
        max_iterations: cfg.max_iterations,
        min_inliers: cfg.min_inliers,
        ..GlobalConfig::default()
    };
    let found = register_by_features(&source, &target, &global)?;
    let icp = Icp {
        config: IcpConfig {
            variant: IcpVariant::PointToPlane,
            max_correspondence_distance: global.max_distance_m,
            max_iterations: ICP_ITERATIONS,
            ..IcpConfig::default()
        },
    };
    let problem = RegistrationProblem { init: found.pose, ..RegistrationProblem::new(source, target) };
    let pose = icp.register(&problem).map_or(found.pose, |r| r.transform);
    Some(GlobalStart { pose, voxel_m: voxel, inliers: found.inliers, matches: found.matches })
}

/// `cloud` with normals from its nearest neighbours, turned towards the camera (the origin).
fn with_normals(cloud: PointCloud, cfg: &GeometryGuideConfig) -> PointCloud {
    let normals = knn_normals(&cloud.points, cfg.normal_neighbours, &Point3::origin());
    PointCloud { normals: Some(normals), ..cloud }
}
