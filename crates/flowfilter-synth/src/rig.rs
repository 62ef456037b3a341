//! A BigBIRD-like capture rig: five Carmine-class RGB-D sensors on an arc from near-horizontal
//! (NP1) to near-top-down (NP5, the reference), looking at a turntable.
//!
//! Frames: the *world* frame is the table frame at angle 0 (origin at the turntable centre on
//! the table surface, z up). At angle `a` the table (and object) is turned by `a` degrees about
//! world z, so `p_world = Rz(a) p_table`, and `H_table_from_reference(a) = Rz(-a) H_world_from_NP5`.

use flowfilter_bigbird::{Calibration, SensorCalibration, SensorId, TablePose, Turntable};
use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, RgbdSensor};
use flowfilter_geometry::{Point3, Pose, Vector3};
use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion};
use std::collections::BTreeMap;

/// One sensor of the rig.
#[derive(Debug, Clone)]
pub struct RigSensor {
    /// Colour + depth camera models, their relative pose and depth scale.
    pub rgbd: RgbdSensor,
    /// Colour camera from world.
    pub h_color_from_world: Pose,
    /// Offset of the structured-light projector from the depth camera, along the depth camera's
    /// +x axis (metres): the stereo baseline of disparity, and the source of projector shadows.
    pub projector_baseline: f64,
    /// `ir_depth_scale` written to the calibration (raw unit = `1e-4 * scale` metres).
    pub ir_depth_scale: f64,
}

impl RigSensor {
    /// Depth camera from world.
    pub fn h_depth_from_world(&self) -> Pose {
        self.rgbd.color_from_depth.inverse() * self.h_color_from_world
    }
}

/// The five-sensor rig.
#[derive(Debug, Clone)]
pub struct Rig {
    /// Sensors NP1..NP5.
    pub sensors: BTreeMap<SensorId, RigSensor>,
}

/// `H_cam_from_world` of an OpenCV camera (x right, y down, z forward) at `eye` looking at `target`.
pub fn look_at(eye: Point3, target: Point3) -> Pose {
    let z = (target - eye).normalize();
    let x = z.cross(&Vector3::z()).normalize();
    let y = z.cross(&x);
    let r_cam_from_world = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r_cam_from_world));
    Pose::from_parts(Translation3::from(-(rot * eye.coords)), rot)
}

/// World from table at turntable angle `deg`.
pub fn world_from_table(deg: f64) -> Pose {
    Pose::rotation(Vector3::z() * deg.to_radians())
}

impl Rig {
    /// The default BigBIRD-like rig: colour 1280x1024 at ~1080 px focal length with small
    /// distortion, depth 640x480 at ~575 px, depth camera 2.5 cm from the colour camera,
    /// projector 7.5 cm from the depth camera, sensors 0.66-0.82 m from the turntable centre at
    /// elevations 8..82 degrees, all in one vertical plane (the BigBIRD arm).
    pub fn bigbird_like() -> Self {
        let mut sensors = BTreeMap::new();
        for id in SensorId::ALL {
            let c = f64::from(id.index());
            let elevation = (8.0 + 18.5 * (c - 1.0)).to_radians();
            let dist = 0.66 + 0.04 * (c - 1.0);
            let target = Point3::new(0.0, 0.0, 0.08);
            let eye = target + Vector3::new(0.004 * c, -dist * elevation.cos(), dist * elevation.sin());
            let h_color_from_world = look_at(eye, target);
            let color = CameraModel::new(
                Intrinsics::new(1076.0 + 2.5 * c, 1075.4 + 2.5 * c, 636.0 + 2.0 * c, 514.0 - 3.0 * c).unwrap(),
                Distortion { k1: 0.03 + 0.004 * c, k2: -0.085 - 0.01 * c, p1: 0.0007, p2: -0.0004 * c, k3: 0.035 },
                ImageSize::new(1280, 1024).unwrap(),
            );
            let depth = CameraModel::new(
                Intrinsics::new(574.0 + c, 573.5 + c, 318.5 + 0.5 * c, 241.0 - 0.5 * c).unwrap(),
                Distortion::NONE,
                ImageSize::new(640, 480).unwrap(),
            );
            // Depth camera 2.5 cm to the colour camera's left (-x), slightly rotated.
            let color_from_depth =
                Pose::new(Vector3::new(-0.025, 0.0008 * c, 0.0), Vector3::new(0.002, -0.003, 0.001 * c));
            let ir_depth_scale = 1.0 + 0.004 * (c - 3.0);
            let rgbd = RgbdSensor::new(depth, color, color_from_depth, ir_depth_scale * 1e-4).unwrap();
            sensors.insert(id, RigSensor { rgbd, h_color_from_world, projector_baseline: 0.075, ir_depth_scale });
        }
        Self { sensors }
    }

    /// World from the reference camera NP5.
    pub fn h_world_from_reference(&self) -> Pose {
        self.sensors[&SensorId::REFERENCE].h_color_from_world.inverse()
    }

    /// `calibration.h5` of this rig.
    pub fn calibration(&self) -> Calibration {
        let h_world_from_ref = self.h_world_from_reference();
        let mut cal = Calibration::default();
        for (id, s) in &self.sensors {
            let h_from_np5 = s.h_color_from_world * h_world_from_ref;
            cal.sensors.insert(
                *id,
                SensorCalibration {
                    rgb_k: s.rgbd.color.intrinsics,
                    rgb_d: s.rgbd.color.distortion,
                    depth_k: s.rgbd.depth.intrinsics,
                    depth_k_key: format!("{id}_ir_K"),
                    ir_depth_scale: s.ir_depth_scale,
                    ir_depth_bias: 0.0,
                    h_from_np5,
                    h_ir_from_np5: s.rgbd.color_from_depth.inverse() * h_from_np5,
                },
            );
        }
        cal
    }

    /// `poses/NP5_{angle}_pose.h5` of this rig.
    pub fn table_pose(&self, angle_deg: u32) -> TablePose {
        TablePose {
            h_table_from_reference: world_from_table(f64::from(angle_deg)).inverse() * self.h_world_from_reference(),
            board_frame_offset: Vector3::zeros(),
        }
    }

    /// `poses/turntable.h5`: the turntable axis in the reference camera frame.
    pub fn turntable(&self) -> Turntable {
        let h = self.h_world_from_reference().inverse();
        Turntable { center: (h * Point3::origin()).coords, normal: h.rotation * Vector3::z() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_points_the_optical_axis_at_the_target() {
        let eye = Point3::new(0.1, -0.7, 0.4);
        let h = look_at(eye, Point3::new(0.0, 0.0, 0.08));
        let t = h * Point3::new(0.0, 0.0, 0.08);
        assert!(t.x.abs() < 1e-12 && t.y.abs() < 1e-12 && t.z > 0.0);
        // World up appears as image "up" (negative y) for a camera above the table.
        assert!((h.rotation * Vector3::z()).y < 0.0);
    }

    #[test]
    fn rig_matches_bigbird_magnitudes() {
        let rig = Rig::bigbird_like();
        let cal = rig.calibration();
        let np1 = &cal.sensors[&SensorId::new(1).unwrap()];
        let t = np1.h_from_np5.translation.vector;
        // NP1 sees the object from the side, NP5 from above: tens of centimetres apart.
        assert!(t.norm() > 0.6 && t.norm() < 1.3, "{t:?}");
        let ref_pose = rig.table_pose(0).h_table_from_reference.translation.vector;
        assert!(ref_pose.norm() > 0.6 && ref_pose.norm() < 1.0, "{ref_pose:?}");
        for s in cal.sensors.values() {
            let d = s.color_from_depth().translation.vector.norm();
            assert!((0.02..0.03).contains(&d));
            assert!((s.rgb_k.fx - 1080.0).abs() < 10.0);
        }
    }
}
