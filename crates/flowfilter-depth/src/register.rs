//! Depth-to-colour registration: depth pixels seen by the depth camera, moved into the colour
//! camera and written onto the colour grid (colour-camera z, metres, 0 = no depth).

use flowfilter_camera::raster::{ScreenVertex, rasterize_grid_depth};
use flowfilter_camera::{RayTable, RgbdSensor};
use flowfilter_geometry::{DepthMap, Mask};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};

/// Every depth pixel with depth, moved into the colour camera and projected (distortion
/// included): its colour-image position and colour-camera z. `None` where there is no depth or
/// the point is behind the colour camera. `depth` may be a crop of the depth image whose top-left
/// pixel is `origin`.
pub fn project_depth_grid(
    depth: &DepthMap,
    origin: (usize, usize),
    sensor: &RgbdSensor,
    depth_rays: &RayTable,
) -> Vec<Option<ScreenVertex>> {
    let w = depth.width();
    // The rigid motion as a matrix: cheaper per point than the quaternion.
    let (r, t) = (sensor.color_from_depth.rotation.to_rotation_matrix(), sensor.color_from_depth.translation.vector);
    depth
        .as_slice()
        .par_iter()
        .enumerate()
        .map(|(k, &z)| {
            if z <= 0.0 {
                return None;
            }
            let p = r * depth_rays.backproject(origin.0 + k % w, origin.1 + k / w, f64::from(z))? + t;
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
    splat_shifted(projected, (0.0, 0.0), width, height, mask)
}

/// [`splat`] of the vertices moved by `-shift` (an image box's corner).
fn splat_shifted(
    projected: &[Option<ScreenVertex>],
    shift: (f32, f32),
    width: usize,
    height: usize,
    mask: Option<&Mask>,
) -> DepthMap {
    // Positive f32 order equals the order of their bit patterns: an atomic min on u32 bits.
    let cells: Vec<AtomicU32> = (0..width * height).map(|_| AtomicU32::new(f32::INFINITY.to_bits())).collect();
    projected.par_iter().flatten().for_each(|v| {
        let v = ScreenVertex { x: v.x - shift.0, y: v.y - shift.1, z: v.z };
        if let Some(k) = nearest_pixel(&v, width, height)
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

/// The bounding box of a mask's set pixels (defined with the shared rasters).
pub use flowfilter_geometry::grid::mask_bbox;

/// The region of the depth grid that can land inside a colour-image box, for any depth
/// between `z_near` and `z_far` (colour-camera z), grown by `margin` pixels:
/// `(x0, y0, x1, y1)` inclusive, clamped to the depth image.
pub fn depth_roi(
    sensor: &RgbdSensor,
    bbox: (usize, usize, usize, usize),
    z_near: f64,
    z_far: f64,
    margin: usize,
) -> (usize, usize, usize, usize) {
    let (dw, dh) = (sensor.depth.size.width as f64, sensor.depth.size.height as f64);
    let depth_from_color = sensor.color_from_depth.inverse();
    let (mut lo, mut hi) = ((f64::INFINITY, f64::INFINITY), (f64::NEG_INFINITY, f64::NEG_INFINITY));
    let (x0, y0, x1, y1) = (bbox.0 as f64, bbox.1 as f64, bbox.2 as f64, bbox.3 as f64);
    for (u, v) in [
        (x0, y0),
        (x1, y0),
        (x0, y1),
        (x1, y1),
        ((x0 + x1) / 2.0, y0),
        ((x0 + x1) / 2.0, y1),
        (x0, (y0 + y1) / 2.0),
        (x1, (y0 + y1) / 2.0),
    ] {
        for i in 0..=8 {
            let z = z_near * (z_far / z_near).powf(f64::from(i) / 8.0);
            let Some(p) = sensor.color.backproject(&flowfilter_camera::Pixel::new(u, v), z) else { continue };
            let Some(q) = sensor.depth.project(&(depth_from_color * p)) else { continue };
            lo = (lo.0.min(q.x), lo.1.min(q.y));
            hi = (hi.0.max(q.x), hi.1.max(q.y));
        }
    }
    if !lo.0.is_finite() {
        return (0, 0, dw as usize - 1, dh as usize - 1);
    }
    let m = margin as f64;
    let clamp = |v: f64, n: f64| v.clamp(0.0, n - 1.0) as usize;
    (clamp(lo.0.floor() - m, dw), clamp(lo.1.floor() - m, dh), clamp(hi.0.ceil() + m, dw), clamp(hi.1.ceil() + m, dh))
}

/// Triangulate the depth grid (two triangles per 2x2 block of valid depth pixels whose depths
/// differ by at most `max_step_m`), rasterise it into the colour image with perspective-correct
/// depth (nearest surface wins), then splat depth pixels that belong to no triangle into pixels
/// still empty. Pixels outside `mask` (when given) are left empty, and only the mask's bounding
/// box is rasterised.
pub fn mesh(
    depth: &DepthMap,
    projected: &[Option<ScreenVertex>],
    width: usize,
    height: usize,
    max_step_m: f64,
    mask: Option<&Mask>,
) -> DepthMap {
    let region = match mask {
        Some(m) => mask_bbox(m),
        None => Some((0, 0, width - 1, height - 1)),
    };
    mesh_in(depth, projected, width, height, max_step_m, mask, region)
}

/// [`mesh`] rasterising only `region` (inclusive box that holds every pixel of `mask`;
/// `None` = nothing to draw).
pub(crate) fn mesh_in(
    depth: &DepthMap,
    projected: &[Option<ScreenVertex>],
    width: usize,
    height: usize,
    max_step_m: f64,
    mask: Option<&Mask>,
    region: Option<(usize, usize, usize, usize)>,
) -> DepthMap {
    let Some((x0, y0, x1, y1)) = region else { return DepthMap::filled(width, height, 0.0) };
    let dw = depth.width();
    let z = depth.as_slice();
    let step = max_step_m as f32;
    // Rasterise only the box: the vertices moved into its frame.
    let (bw, bh) = (x1 - x0 + 1, y1 - y0 + 1);
    let shift = (x0 as f32, y0 as f32);
    let g = rasterize_grid_depth(bw, bh, dw, projected, shift, |[a, b, c]| {
        let (za, zb, zc) = (z[a], z[b], z[c]);
        za.max(zb).max(zc) - za.min(zb).min(zc) <= step
    });
    let dots = splat_shifted(projected, shift, bw, bh, None);
    let mut out = DepthMap::filled(width, height, 0.0);
    out.as_mut_slice()[y0 * width..(y1 + 1) * width].par_chunks_mut(width).enumerate().for_each(|(by, row)| {
        for bx in 0..bw {
            let (k, kb) = ((y0 + by) * width + x0 + bx, by * bw + bx);
            if mask.is_some_and(|m| !m.as_slice()[k]) {
                continue;
            }
            row[x0 + bx] = if g[kb].is_finite() { g[kb] } else { dots.as_slice()[kb] };
        }
    });
    out
}
