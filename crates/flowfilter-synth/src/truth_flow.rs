//! Ground-truth optical flow between two rendered colour views of a turntable scene: every
//! object pixel of the first view is traced to its surface point (from the z-buffer's triangle
//! and perspective-correct barycentrics), moved by the known turntable and camera motion,
//! projected into the second view (distortion included) and tested for visibility against the
//! second view's z-buffer.

use crate::capture::render_gbuffer;
use crate::rig::{Rig, world_from_table};
use crate::scene::Scene;
use flowfilter_bigbird::FrameId;
use flowfilter_camera::raster::{GBuffer, NO_TRIANGLE};
use flowfilter_geometry::{Grid, Mask, Pose};
use nalgebra::Point3;
use rayon::prelude::*;

/// Exact flow from one colour view to another.
#[derive(Debug, Clone)]
pub struct TrueFlow {
    /// `(u, v)` in pixels for every object pixel of the first view (its point's position in the
    /// second view minus its own); `[0, 0]` elsewhere.
    pub flow: Grid<[f32; 2]>,
    /// Object pixels of the first view whose surface point is visible in the second view.
    pub visible: Mask,
    /// Object pixels of the first view whose point is hidden in the second view (by the object
    /// itself or the table) or falls outside its image.
    pub occluded: Mask,
}

impl TrueFlow {
    /// The object pixels of the first view (visible or occluded in the second).
    pub fn object(&self) -> Mask {
        Mask::from_fn(self.visible.width(), self.visible.height(), |x, y| {
            *self.visible.at(x, y) || *self.occluded.at(x, y)
        })
    }

    /// Number of object pixels of the first view.
    pub fn object_pixels(&self) -> usize {
        self.object().as_slice().iter().filter(|&&o| o).count()
    }

    /// Fraction of the object pixels that are occluded in the second view (0 when there are none).
    pub fn occluded_fraction(&self) -> f64 {
        let n = self.object_pixels();
        if n == 0 { 0.0 } else { self.occluded.as_slice().iter().filter(|&&o| o).count() as f64 / n as f64 }
    }
}

/// A colour view: its G-buffer and the table-to-camera transform.
struct View {
    g: GBuffer,
    h_cam_from_table: Pose,
}

fn view(scene: &Scene, rig: &Rig, id: FrameId) -> View {
    let s = &rig.sensors[&id.sensor];
    let h_cam_from_table = s.h_color_from_world * world_from_table(f64::from(id.angle));
    View { g: render_gbuffer(scene, &s.rgbd.color, &h_cam_from_table), h_cam_from_table }
}

/// Table-frame surface point seen by pixel `k` of a G-buffer (`None` where nothing is hit).
fn surface_point(scene: &Scene, g: &GBuffer, k: usize) -> Option<Point3<f64>> {
    let t = g.triangle[k];
    if t == NO_TRIANGLE {
        return None;
    }
    let [i0, i1, i2] = scene.triangles[t as usize].map(|i| scene.positions[i as usize].cast::<f64>());
    let [b1, b2] = g.bary[k].map(f64::from);
    Some(Point3::from(i0.coords * (1.0 - b1 - b2) + i1.coords * b1 + i2.coords * b2))
}

/// The exact flow from colour view `from` to colour view `to` (any sensors and angles of
/// `rig`). A point counts as visible when the second view's surface at one of the four pixel
/// centres around its projection lies within `tolerance_m` of the point's depth there.
pub fn true_flow(scene: &Scene, rig: &Rig, from: FrameId, to: FrameId, tolerance_m: f64) -> TrueFlow {
    let (a, b) = (view(scene, rig, from), view(scene, rig, to));
    let cam_b = &rig.sensors[&to.sensor].rgbd.color;
    let (w, h) = (a.g.width, a.g.height);
    let (bw, bh) = (b.g.width, b.g.height);
    let n_obj = scene.object_triangles() as u32;
    let traced: Vec<Option<([f32; 2], bool)>> = (0..w * h)
        .into_par_iter()
        .map(|k| {
            if a.g.triangle[k] >= n_obj {
                return None;
            }
            let p = surface_point(scene, &a.g, k)?;
            let q = b.h_cam_from_table * p;
            let flow = |px: f64, py: f64| [(px - (k % w) as f64) as f32, (py - (k / w) as f64) as f32];
            let Some(pix) = cam_b.project(&q) else { return Some(([f32::NAN; 2], false)) };
            let f = flow(pix.x, pix.y);
            let (x0, y0) = (pix.x.floor(), pix.y.floor());
            let visible = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)].iter().any(|(dx, dy)| {
                let (x, y) = (x0 + dx, y0 + dy);
                if x < 0.0 || y < 0.0 || x >= bw as f64 || y >= bh as f64 {
                    return false;
                }
                let z = f64::from(b.g.depth[y as usize * bw + x as usize]);
                z.is_finite() && (z - q.z).abs() <= tolerance_m
            });
            Some((f, visible && pix.x >= -0.5 && pix.y >= -0.5 && pix.x <= bw as f64 - 0.5 && pix.y <= bh as f64 - 0.5))
        })
        .collect();
    let flow = Grid::from_vec(
        w,
        h,
        traced.iter().map(|t| t.map_or([0.0; 2], |(f, _)| if f[0].is_finite() { f } else { [0.0; 2] })).collect(),
    )
    .expect("sized");
    let visible = Mask::from_vec(w, h, traced.iter().map(|t| t.is_some_and(|(_, v)| v)).collect()).expect("sized");
    let occluded = Mask::from_vec(w, h, traced.iter().map(|t| t.is_some_and(|(_, v)| !v)).collect()).expect("sized");
    TrueFlow { flow, visible, occluded }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::procedural;
    use flowfilter_bigbird::SensorId;

    fn scene() -> Scene {
        Scene::new(procedural("box", 3).unwrap().placed_on_table(0.01, -0.005), 3)
    }

    fn id(sensor: u8, angle: u32) -> FrameId {
        FrameId { sensor: SensorId::new(sensor).unwrap(), angle }
    }

    #[test]
    fn same_view_has_zero_flow_and_everything_visible() {
        let (scene, rig) = (scene(), Rig::bigbird_like());
        let t = true_flow(&scene, &rig, id(3, 30), id(3, 30), 0.003);
        assert!(t.object_pixels() > 10_000, "{}", t.object_pixels());
        assert_eq!(t.occluded_fraction(), 0.0);
        let max = t.flow.as_slice().iter().map(|f| f[0].abs().max(f[1].abs())).fold(0.0f32, f32::max);
        assert!(max < 1e-3, "{max}");
    }

    /// Forward flow then backward flow (each from its own z-buffer) returns to the start.
    #[test]
    fn forward_and_backward_flows_are_inverse() {
        let (scene, rig) = (scene(), Rig::bigbird_like());
        for (a, b) in [(id(3, 30), id(3, 45)), (id(1, 0), id(1, 9)), (id(2, 60), id(4, 60))] {
            let fwd = true_flow(&scene, &rig, a, b, 0.003);
            let bwd = true_flow(&scene, &rig, b, a, 0.003);
            let w = fwd.flow.width();
            let mut errors: Vec<f32> = vec![];
            for (k, f) in fwd.flow.as_slice().iter().enumerate() {
                if !fwd.visible.as_slice()[k] {
                    continue;
                }
                let (x, y) = ((k % w) as f32 + f[0], (k / w) as f32 + f[1]);
                if x < 0.0 || y < 0.0 {
                    continue;
                }
                // The backward flow, bilinear between four visible pixels.
                let (xi, yi) = (x.floor() as usize, y.floor() as usize);
                let (fx, fy) = (x - xi as f32, y - yi as f32);
                let corners = [(0, 0), (1, 0), (0, 1), (1, 1)];
                if !corners.iter().all(|(dx, dy)| bwd.visible.get(xi + dx, yi + dy).copied().unwrap_or(false)) {
                    continue;
                }
                let g = |c: usize| {
                    let at = |dx: usize, dy: usize| bwd.flow.at(xi + dx, yi + dy)[c];
                    (at(0, 0) * (1.0 - fx) + at(1, 0) * fx) * (1.0 - fy) + (at(0, 1) * (1.0 - fx) + at(1, 1) * fx) * fy
                };
                let back = (x + g(0) - (k % w) as f32, y + g(1) - (k / w) as f32);
                errors.push(back.0.hypot(back.1));
            }
            errors.sort_by(f32::total_cmp);
            let median = errors[errors.len() / 2];
            let p90 = errors[errors.len() * 9 / 10];
            assert!(errors.len() > 5_000, "{a:?} -> {b:?}: {} pairs", errors.len());
            // The round trip returns to the start up to the flow's change across half a pixel.
            assert!(median < 0.01 && p90 < 0.05, "{a:?} -> {b:?}: median {median}, p90 {p90}");
        }
    }

    #[test]
    fn turning_the_object_away_occludes_its_front() {
        let (scene, rig) = (scene(), Rig::bigbird_like());
        let small = true_flow(&scene, &rig, id(3, 0), id(3, 3), 0.003).occluded_fraction();
        let half_turn = true_flow(&scene, &rig, id(3, 0), id(3, 180), 0.003).occluded_fraction();
        assert!(small < 0.1, "{small}");
        assert!(half_turn > 0.6, "{half_turn}");
    }
}
