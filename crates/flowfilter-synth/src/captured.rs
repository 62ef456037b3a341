//! Twins of captured scenes: a real RGB-D frame turned into a textured surface
//! ([`surface_from_rgbd`]) and rendered again from another camera pose through the same sensor
//! ([`render_surface_view`]), with the noise profile's depth and colour noise and the frame's
//! effects. A pair of such views has the real frame's texture, geometry, depth holes and camera
//! (its own depth camera, registered to colour by whoever reads the frame, as the real one), and
//! an exact relative pose: what a real pair would be with a perfect calibration and the
//! synthetic model of the sensor.
//!
//! The surface's colour already holds the scene's light, so it is rendered as it is (no shading).
//! Its depth is smoothed before it is meshed, so that the rendered depth's roughness is the
//! profile's, not the real frame's noise twice.

use crate::capture::RenderedView;
use crate::error::{SynthError, positive_and_finite};
use crate::mesh::TexturedMesh;
use crate::twin::{FrameRender, TwinOptions, TwinView, frame_seed};
use flowfilter_camera::{Pixel, RgbdSensor};
use flowfilter_geometry::{DepthMap, Pose, RawDepth};
use image::RgbImage;
use nalgebra::Point3;
use std::path::PathBuf;
use std::sync::Arc;

/// How a captured frame becomes a surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceOptions {
    /// Neighbouring depth readings further apart than this fraction of their depth are not
    /// joined (a depth edge, not a surface).
    pub max_step_fraction: f64,
    /// Half-width of the window the depth is smoothed over, depth pixels (0 = as read).
    pub smoothing_radius_px: usize,
    /// Readings of the window further than this from the centre's are left out of its mean,
    /// metres (edges stay sharp).
    pub smoothing_gate_m: f64,
    /// Holes of the depth up to this many pixels from a reading are filled from their
    /// neighbours (the nearest surface's), so that the surface keeps the colour seen there: a
    /// real sensor's holes (dark texture, grazing surfaces) are in its depth, not in its colour.
    pub fill_holes_px: usize,
}

impl Default for SurfaceOptions {
    /// Joins readings within 3% of their depth (1.5 cm at 0.5 m); a 5 x 5 mean within 1 cm;
    /// holes filled up to 12 px from a reading.
    fn default() -> Self {
        Self { max_step_fraction: 0.03, smoothing_radius_px: 2, smoothing_gate_m: 0.01, fill_holes_px: 12 }
    }
}

/// The surface a captured frame shows, in its colour camera's frame: a vertex per depth reading
/// (smoothed), joined into triangles between neighbouring readings on one surface, textured by
/// the colour image where the reading falls in it.
///
/// # Errors
/// [`SynthError::BadOption`] when the images do not fit the sensor or an option is out of range;
/// [`SynthError::DegenerateMesh`] when no triangle can be made (no depth).
///
/// # Example
/// ```
/// use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, RgbdSensor};
/// use flowfilter_geometry::RawDepth;
/// use flowfilter_synth::{SurfaceOptions, surface_from_rgbd};
///
/// let camera = CameraModel::new(Intrinsics::new(100.0, 100.0, 32.0, 24.0)?, Distortion::NONE, ImageSize::new(64, 48)?);
/// let sensor = RgbdSensor::registered(camera, 1e-3)?;
/// let color = image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([(x * 4) as u8, (y * 5) as u8, 90]));
/// let depth = RawDepth::from_vec(64, 48, vec![600; 64 * 48])?; // a wall 0.6 m away
/// let surface = surface_from_rgbd(&color, &depth, &sensor, &SurfaceOptions::default())?;
/// assert_eq!(surface.triangles.len(), 2 * 63 * 47);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn surface_from_rgbd(
    color: &RgbImage,
    depth: &RawDepth,
    sensor: &RgbdSensor,
    opts: &SurfaceOptions,
) -> Result<TexturedMesh, SynthError> {
    check_images(color, depth, sensor)?;
    check_surface_options(opts)?;
    let metres = filled(smoothed_depth(depth, sensor, opts), opts);
    let (w, h) = metres.dims();
    let (cw, ch) = (f64::from(color.width()), f64::from(color.height()));
    // A vertex per reading whose point lands in the colour image.
    let mut index = vec![u32::MAX; w * h];
    let (mut positions, mut uvs) = (vec![], vec![]);
    for y in 0..h {
        for x in 0..w {
            let z = f64::from(*metres.at(x, y));
            if z <= 0.0 {
                continue;
            }
            let Some(p) = sensor.depth_pixel_to_color_frame(&Pixel::new(x as f64, y as f64), z) else { continue };
            let Some(c) = sensor.color.project(&p) else { continue };
            if c.x < -0.5 || c.y < -0.5 || c.x > cw - 0.5 || c.y > ch - 0.5 {
                continue;
            }
            index[y * w + x] = positions.len() as u32;
            positions.push(Point3::new(p.x as f32, p.y as f32, p.z as f32));
            // OBJ convention: v = 0 at the bottom row.
            uvs.push([((c.x + 0.5) / cw) as f32, (1.0 - (c.y + 0.5) / ch) as f32]);
        }
    }
    let joined = |ks: [usize; 3]| {
        let zs = ks.map(|k| f64::from(metres.as_slice()[k]));
        let (lo, hi) = zs.iter().fold((f64::MAX, f64::MIN), |(lo, hi), &z| (lo.min(z), hi.max(z)));
        ks.iter().all(|&k| index[k] != u32::MAX) && hi - lo <= opts.max_step_fraction * lo
    };
    let mut triangles = vec![];
    for y in 0..h.saturating_sub(1) {
        for x in 0..w.saturating_sub(1) {
            let (a, b, c, d) = (y * w + x, y * w + x + 1, (y + 1) * w + x, (y + 1) * w + x + 1);
            for t in [[a, c, b], [b, c, d]] {
                if joined(t) {
                    triangles.push(t.map(|k| index[k]));
                }
            }
        }
    }
    TexturedMesh::new(PathBuf::from("captured:rgbd"), positions, uvs, triangles, Arc::new(color.clone()))
}

/// The frame's depth in metres, each reading replaced by the mean of the readings of its window
/// within the gate of it.
fn smoothed_depth(depth: &RawDepth, sensor: &RgbdSensor, opts: &SurfaceOptions) -> DepthMap {
    let (w, h) = depth.dims();
    let z = |x: usize, y: usize| sensor.metric_depth(*depth.at(x, y)).unwrap_or(0.0);
    let r = opts.smoothing_radius_px;
    let values = (0..w * h)
        .map(|k| {
            let (x, y) = (k % w, k / w);
            let centre = z(x, y);
            if centre <= 0.0 || r == 0 {
                return centre as f32;
            }
            let (mut sum, mut n) = (0.0, 0.0);
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                    let v = z(xx, yy);
                    if v > 0.0 && (v - centre).abs() <= opts.smoothing_gate_m {
                        sum += v;
                        n += 1.0;
                    }
                }
            }
            (sum / n) as f32
        })
        .collect();
    DepthMap::from_vec(w, h, values).expect("sized")
}

/// `depth` with its holes filled [`SurfaceOptions::fill_holes_px`] deep: pass after pass, an
/// empty pixel with at least two read neighbours (of its 8) takes the mean of those within the
/// smoothing gate of the nearest of them.
fn filled(mut depth: DepthMap, opts: &SurfaceOptions) -> DepthMap {
    let (w, h) = depth.dims();
    let gate = opts.smoothing_gate_m as f32;
    // Only the empty pixels are visited, pass after pass.
    let mut empty: Vec<usize> = (0..w * h).filter(|&k| depth.as_slice()[k] <= 0.0).collect();
    for _ in 0..opts.fill_holes_px {
        let src = depth.as_slice();
        let updates: Vec<(usize, f32)> = empty
            .iter()
            .filter_map(|&k| {
                let (x, y) = (k % w, k / w);
                let mut near = [0.0f32; 8];
                let mut n = 0;
                for yy in y.saturating_sub(1)..(y + 2).min(h) {
                    for xx in x.saturating_sub(1)..(x + 2).min(w) {
                        let v = src[yy * w + xx];
                        if v > 0.0 {
                            near[n] = v;
                            n += 1;
                        }
                    }
                }
                if n < 2 {
                    return None;
                }
                let nearest = near[..n].iter().copied().fold(f32::MAX, f32::min);
                let (sum, count) =
                    near[..n].iter().filter(|&&v| v - nearest <= gate).fold((0.0, 0.0), |(s, c), &v| (s + v, c + 1.0));
                Some((k, sum / count))
            })
            .collect();
        if updates.is_empty() {
            break;
        }
        for &(k, v) in &updates {
            depth.as_mut_slice()[k] = v;
        }
        empty.retain(|&k| depth.as_slice()[k] <= 0.0);
    }
    depth
}

/// Render `surface` through `sensor` at `camera_from_surface`, where it shows nothing showing
/// `backdrop` (another surface and its pose) if given, with `opts`' noise and the effects of
/// frame `frame`. The depth is the sensor's depth camera's (registered to colour only when the
/// sensor is); the masks are the surface's pixels (the backdrop is not the object).
///
/// # Errors
/// [`SynthError::BadOption`] for a depth focal length that is not positive and finite.
///
/// # Example
/// ```
/// use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, RgbdSensor};
/// use flowfilter_geometry::{Pose, RawDepth};
/// use flowfilter_synth::{FrameEffects, SurfaceOptions, TwinOptions, render_surface_view, surface_from_rgbd};
///
/// let camera = CameraModel::new(Intrinsics::new(100.0, 100.0, 32.0, 24.0)?, Distortion::NONE, ImageSize::new(64, 48)?);
/// let sensor = RgbdSensor::registered(camera, 1e-3)?;
/// let color = image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([(x * 4) as u8, (y * 5) as u8, 90]));
/// let depth = RawDepth::from_vec(64, 48, vec![600; 64 * 48])?;
/// let surface = surface_from_rgbd(&color, &depth, &sensor, &SurfaceOptions::default())?;
/// let exact = TwinOptions { noise: None, effects: FrameEffects::NONE, mask_offset_px: (0, 0), ..TwinOptions::default() };
/// let view = render_surface_view(&surface, None, &sensor, &Pose::translation(0.05, 0.0, 0.0), &exact, 1)?;
/// assert_eq!(*view.depth.at(10, 24), 600); // the wall, moved sideways
/// assert!(!*view.true_mask.at(2, 24)); // its left edge moved right by 100 * 0.05 / 0.6 = 8 px
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn render_surface_view(
    surface: &TexturedMesh,
    backdrop: Option<(&TexturedMesh, Pose)>,
    sensor: &RgbdSensor,
    camera_from_surface: &Pose,
    opts: &TwinOptions,
    frame: u32,
) -> Result<TwinView, SynthError> {
    positive_and_finite(&[("depth_focal_px", opts.depth_focal_px)])?;
    let mut frame_render = FrameRender::new(sensor, opts, frame_seed(opts.seed, frame, 0x5CA7), true);
    let mut view = frame_render.render(surface, camera_from_surface);
    if let Some((mesh, pose)) = backdrop {
        let behind = frame_render.render(mesh, &pose);
        fill_from(&mut view, &behind);
    }
    Ok(frame_render.finish(view))
}

/// Where `view` shows no surface, it shows `other`'s (colour on the colour grid, depth on the
/// depth grid); its masks stay its own.
fn fill_from(view: &mut RenderedView, other: &RenderedView) {
    let width = view.color.width() as usize;
    for (k, &z) in view.color_depth.as_slice().iter().enumerate() {
        if z <= 0.0 && other.color_depth.as_slice()[k] > 0.0 {
            let (x, y) = ((k % width) as u32, (k / width) as u32);
            view.color.put_pixel(x, y, *other.color.get_pixel(x, y));
        }
    }
    for (k, z) in view.clean_depth.as_mut_slice().iter_mut().enumerate() {
        if *z <= 0.0 && other.clean_depth.as_slice()[k] > 0.0 {
            *z = other.clean_depth.as_slice()[k];
            view.raw_depth.as_mut_slice()[k] = other.raw_depth.as_slice()[k];
        }
    }
}

fn check_images(color: &RgbImage, depth: &RawDepth, sensor: &RgbdSensor) -> Result<(), SynthError> {
    let fits = |(w, h): (usize, usize), camera: &flowfilter_camera::CameraModel| {
        w == camera.size.width as usize && h == camera.size.height as usize
    };
    let (cw, ch) = (color.width() as usize, color.height() as usize);
    for (field, dims, camera) in [("color", (cw, ch), &sensor.color), ("depth", depth.dims(), &sensor.depth)] {
        if !fits(dims, camera) {
            return Err(SynthError::BadOption {
                field,
                message: format!(
                    "the image is {}x{}, its camera {}x{}",
                    dims.0, dims.1, camera.size.width, camera.size.height
                ),
            });
        }
    }
    Ok(())
}

fn check_surface_options(opts: &SurfaceOptions) -> Result<(), SynthError> {
    positive_and_finite(&[("max_step_fraction", opts.max_step_fraction), ("smoothing_gate_m", opts.smoothing_gate_m)])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::FrameEffects;
    use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics};
    use flowfilter_geometry::Vector3;

    /// A sensor with its own depth camera 2.5 cm beside the colour camera, as the SR300's.
    fn sensor() -> RgbdSensor {
        let color = CameraModel::new(
            Intrinsics::new(300.0, 300.0, 79.5, 59.5).unwrap(),
            Distortion::NONE,
            ImageSize::new(160, 120).unwrap(),
        );
        let depth = CameraModel::new(
            Intrinsics::new(240.0, 240.0, 80.0, 60.0).unwrap(),
            Distortion::NONE,
            ImageSize::new(160, 120).unwrap(),
        );
        RgbdSensor::new(depth, color, Pose::translation(0.025, 0.0, 0.0), 1e-3).unwrap()
    }

    /// A box 0.1 m nearer than a wall at 0.7 m, the colour a ramp with a bright square.
    fn frame() -> (RgbImage, RawDepth) {
        let color = RgbImage::from_fn(160, 120, |x, y| {
            let on = (60..90).contains(&x) && (40..70).contains(&y);
            image::Rgb(if on { [240, 200, 40] } else { [(x / 2) as u8, (y * 2) as u8, 60] })
        });
        let depth = RawDepth::from_vec(
            160,
            120,
            (0..160 * 120)
                .map(|k| if (50..90).contains(&(k % 160)) && (30..70).contains(&(k / 160)) { 600 } else { 700 })
                .collect(),
        )
        .unwrap();
        (color, depth)
    }

    fn exact() -> TwinOptions {
        TwinOptions { noise: None, effects: FrameEffects::NONE, mask_offset_px: (0, 0), ..TwinOptions::default() }
    }

    /// Rendered from where it was captured, the surface gives the frame back: the same colour
    /// (away from the edges of the box, which the surface does not join) and the same depth.
    #[test]
    fn a_surface_seen_from_its_own_camera_gives_its_frame_back() {
        let (color, depth) = frame();
        let surface = surface_from_rgbd(&color, &depth, &sensor(), &SurfaceOptions::default()).unwrap();
        let view = render_surface_view(&surface, None, &sensor(), &Pose::identity(), &exact(), 1).unwrap();
        assert_eq!(view.true_mask.dims(), (160, 120));
        let (mut same, mut compared) = (0, 0);
        for y in 5..115 {
            for x in 5..155 {
                if *view.true_mask.at(x, y) {
                    compared += 1;
                    let (a, b) = (view.color.get_pixel(x as u32, y as u32).0, color.get_pixel(x as u32, y as u32).0);
                    same += usize::from((0..3).all(|c| a[c].abs_diff(b[c]) <= 3));
                }
            }
        }
        assert!(compared > 14_000 && same * 100 >= compared * 95, "{same} of {compared} pixels alike");
        let (mut depth_same, mut read) = (0, 0);
        for (k, &d) in depth.as_slice().iter().enumerate() {
            let r = view.depth.as_slice()[k];
            if r > 0 {
                read += 1;
                depth_same += usize::from(r.abs_diff(d) <= 1);
            }
        }
        // The depth camera sees wider than the colour camera: 80% of each side of it is textured.
        assert!(read > 12_000 && depth_same * 100 >= read * 95, "{depth_same} of {read} readings alike");
    }

    /// Moved, the surface appears where the motion puts it: the bright square of the box (0.6 m
    /// away) slides by fx * t / z, and where the surface no longer covers the image the
    /// backdrop shows, not the background.
    #[test]
    fn a_moved_surface_is_seen_where_the_motion_puts_it_over_its_backdrop() {
        let (color, depth) = frame();
        let s = sensor();
        let surface = surface_from_rgbd(&color, &depth, &s, &SurfaceOptions::default()).unwrap();
        let bright = |img: &RgbImage| {
            let xs: Vec<u32> =
                img.enumerate_pixels().filter(|(_, _, p)| p.0 == [240, 200, 40]).map(|(x, _, _)| x).collect();
            xs.iter().map(|&x| f64::from(x)).sum::<f64>() / xs.len() as f64
        };
        let motion = Pose::new(Vector3::new(-0.04, 0.0, 0.0), Vector3::zeros());
        let view = render_surface_view(&surface, None, &s, &motion, &exact(), 1).unwrap();
        let moved = bright(&view.color) - bright(&color);
        assert!((moved - (-300.0 * 0.04 / 0.6)).abs() < 1.0, "moved {moved:.2} px");
        // The right edge is uncovered: background without a backdrop, the backdrop's colour with one.
        assert_eq!(view.color.get_pixel(158, 10).0, [38, 38, 42]);
        let with = render_surface_view(&surface, Some((&surface, Pose::identity())), &s, &motion, &exact(), 1).unwrap();
        assert_eq!(with.color.get_pixel(158, 10).0, color.get_pixel(158, 10).0);
        assert!(!*with.true_mask.at(158, 10), "the backdrop is not the object");
    }

    /// A hole in the depth (a dark patch the sensor does not read) is covered by the surface,
    /// and its colour seen, when it is within the fill's reach of a reading; without the fill
    /// it shows the background.
    #[test]
    fn holes_within_the_fills_reach_keep_their_colour() {
        let (color, mut depth) = frame();
        for y in 10..24 {
            for x in 100..114 {
                *depth.at_mut(x, y) = 0; // 14 x 14 depth pixels: 7 from a reading at most
            }
        }
        let s = sensor();
        let seen = |fill: usize| {
            let opts = SurfaceOptions { fill_holes_px: fill, ..SurfaceOptions::default() };
            let surface = surface_from_rgbd(&color, &depth, &s, &opts).unwrap();
            render_surface_view(&surface, None, &s, &Pose::identity(), &exact(), 1).unwrap()
        };
        // The hole's middle, on the colour grid: depth pixel (107, 17) at 0.7 m.
        let p = s.depth_pixel_to_color_pixel(&Pixel::new(107.0, 17.0), 0.7).unwrap().0;
        let (x, y) = (p.x.round() as u32, p.y.round() as u32);
        assert_eq!(seen(0).color.get_pixel(x, y).0, [38, 38, 42], "no fill: the background");
        let filled = seen(12);
        let (a, b) = (filled.color.get_pixel(x, y).0, color.get_pixel(x, y).0);
        assert!((0..3).all(|c| a[c].abs_diff(b[c]) <= 3), "{a:?} against {b:?}");
        assert_eq!(*filled.depth.at(107, 17), 700, "the hole takes its surroundings' depth");
    }

    #[test]
    fn images_that_do_not_fit_the_sensor_are_refused() {
        let (color, _) = frame();
        let small = RawDepth::from_vec(80, 60, vec![600; 80 * 60]).unwrap();
        let e = surface_from_rgbd(&color, &small, &sensor(), &SurfaceOptions::default()).unwrap_err().to_string();
        assert!(e.contains("depth") && e.contains("80x60"), "{e}");
        let (_, depth) = frame();
        let bad = SurfaceOptions { max_step_fraction: f64::NAN, ..SurfaceOptions::default() };
        let e = surface_from_rgbd(&color, &depth, &sensor(), &bad).unwrap_err().to_string();
        assert!(e.contains("max_step_fraction"), "{e}");
        let empty = RawDepth::from_vec(160, 120, vec![0; 160 * 120]).unwrap();
        assert!(surface_from_rgbd(&color, &empty, &sensor(), &SurfaceOptions::default()).is_err());
    }
}
