//! Depth-to-colour registration: depth pixels seen by the depth camera, moved into the colour
//! camera and written onto the colour grid (colour-camera z, metres, 0 = no depth).

use flowfilter_camera::raster::{ScreenVertex, rasterize};
use flowfilter_camera::{RayTable, RgbdSensor};
use flowfilter_geometry::{DepthMap, Mask};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};

/// Every depth pixel with depth, moved into the colour camera and projected (distortion
/// included): its colour-image position and colour-camera z. `None` where there is no depth or
/// the point is behind the colour camera.
pub fn project_depth_grid(depth: &DepthMap, sensor: &RgbdSensor, depth_rays: &RayTable) -> Vec<Option<ScreenVertex>> {
    let w = depth.width();
    depth
        .as_slice()
        .par_iter()
        .enumerate()
        .map(|(k, &z)| {
            if z <= 0.0 {
                return None;
            }
            let p = sensor.color_from_depth * depth_rays.backproject(k % w, k / w, f64::from(z))?;
            let q = sensor.color.project(&p)?;
            Some(ScreenVertex { x: q.x as f32, y: q.y as f32, z: p.z as f32 })
        })
        .collect()
}

fn nearest_pixel(v: &ScreenVertex, w: usize, h: usize) -> Option<usize> {
    let (u, r) = (v.x.round(), v.y.round());
    (u >= 0.0 && r >= 0.0 && (u as usize) < w && (r as usize) < h).then(|| r as usize * w + u as usize)
}

/// Splat projected depth pixels onto the nearest colour pixel; the nearest surface wins
/// (the BigBIRD tools' registration). Pixels outside `mask` (when given) are left empty.
pub fn splat(projected: &[Option<ScreenVertex>], width: usize, height: usize, mask: Option<&Mask>) -> DepthMap {
    // Positive f32 order equals the order of their bit patterns: an atomic min on u32 bits.
    let cells: Vec<AtomicU32> = (0..width * height).map(|_| AtomicU32::new(f32::INFINITY.to_bits())).collect();
    projected.par_iter().flatten().for_each(|v| {
        if let Some(k) = nearest_pixel(v, width, height)
            && mask.is_none_or(|m| m.as_slice()[k])
            && v.z > 0.0
        {
            cells[k].fetch_min(v.z.to_bits(), Ordering::Relaxed);
        }
    });
    let data = cells
        .into_iter()
        .map(|c| {
            let z = f32::from_bits(c.into_inner());
            if z.is_finite() { z } else { 0.0 }
        })
        .collect();
    DepthMap::from_vec(width, height, data).expect("sized")
}

/// Triangulate the depth grid (two triangles per 2x2 block of valid depth pixels whose depths
/// differ by at most `max_step_m`), rasterise it into the colour image with perspective-correct
/// depth (nearest surface wins), then splat depth pixels that belong to no triangle into pixels
/// still empty. Pixels outside `mask` (when given) are left empty.
pub fn mesh(
    depth: &DepthMap,
    projected: &[Option<ScreenVertex>],
    width: usize,
    height: usize,
    max_step_m: f64,
    mask: Option<&Mask>,
) -> DepthMap {
    let (dw, dh) = depth.dims();
    let z = depth.as_slice();
    let step = max_step_m as f32;
    let ok = |a: usize, b: usize, c: usize| {
        let (za, zb, zc) = (z[a], z[b], z[c]);
        projected[a].is_some()
            && projected[b].is_some()
            && projected[c].is_some()
            && za.max(zb).max(zc) - za.min(zb).min(zc) <= step
    };
    let triangles: Vec<[u32; 3]> = (0..dh.saturating_sub(1))
        .into_par_iter()
        .flat_map_iter(|y| {
            let mut out = Vec::new();
            for x in 0..dw - 1 {
                let (a, b, c, d) = (y * dw + x, y * dw + x + 1, (y + 1) * dw + x, (y + 1) * dw + x + 1);
                if ok(a, b, d) {
                    out.push([a as u32, b as u32, d as u32]);
                }
                if ok(a, d, c) {
                    out.push([a as u32, d as u32, c as u32]);
                }
            }
            out
        })
        .collect();
    let g = rasterize(width, height, projected, &triangles);
    let dots = splat(projected, width, height, None);
    let data = (0..width * height)
        .into_par_iter()
        .map(|k| {
            if mask.is_some_and(|m| !m.as_slice()[k]) {
                0.0
            } else if g.depth[k].is_finite() {
                g.depth[k]
            } else {
                dots.as_slice()[k]
            }
        })
        .collect();
    DepthMap::from_vec(width, height, data).expect("sized")
}
