//! The synthetic twin of a real posed sequence's pairs (`bench-real --twin`): each pair's frames
//! rendered from its model frame's own surface ([`flowfilter_synth::surface_from_rgbd`]), the
//! model frame from where it was taken and the target frame from where the calibrated poses put
//! the target camera, through the sequence's sensor, with the SR300 shelf profile's noise, depth
//! warp and effects. Where the model frame's surface does not reach (the image's new side, what
//! it hid), the target frame's own surface shows, and each twin keeps depth readings only where
//! its real frame has them. The truth is then exact, and the texture, geometry, depth holes,
//! views and motions are the real pair's: what the pair would give with a perfect calibration
//! and the synthetic model of the sensor.

use crate::realsense::PosedFrames;
use flowfilter_pipeline::{Mask, Pose, RgbdFrame};
use flowfilter_synth::{
    FrameEffects, NoiseProfile, SurfaceOptions, TexturedMesh, TwinOptions, render_surface_view, surface_from_rgbd,
};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};

/// The twin's options for a run seeded with `seed` under `noise` (the SR300 shelf profile by
/// default): the SR300 shelf effects, the depth camera's focal length.
pub fn twin_options(seed: u64, noise: Option<NoiseProfile>) -> TwinOptions {
    TwinOptions {
        noise,
        effects: FrameEffects::SR300_SHELF,
        depth_focal_px: 477.0,
        projector_baseline_m: 0.05,
        mask_offset_px: (0, 0),
        seed,
    }
}

/// Holes of a backdrop surface filled up to this many pixels from a reading: every hole of a
/// 640 x 480 frame.
const BACKDROP_FILL_PX: usize = 640;

/// The real frames' surfaces by frame: the surface seen from other poses (holes filled up to
/// 12 px), and the backdrop seen only from the frame's own pose (every hole filled, so that the
/// frame's colour shows wherever no surface reaches: its dark and far parts, which have no
/// depth).
pub struct Surfaces(BTreeMap<u32, (TexturedMesh, TexturedMesh)>);

impl Surfaces {
    /// The surfaces of the frames `ims` of `whole` (the real frames).
    ///
    /// # Errors
    /// A message naming the sequence and the frame whose surface cannot be made.
    pub fn of(whole: &BTreeMap<u32, RgbdFrame>, ims: &BTreeSet<u32>, label: &str) -> Result<Self, String> {
        let built = ims
            .par_iter()
            .map(|&im| {
                let f = whole.get(&im).ok_or_else(|| format!("{label}: frame {im} could not be read"))?;
                let surface = |opts: &SurfaceOptions| {
                    surface_from_rgbd(&f.color, &f.depth, &f.sensor, opts)
                        .map_err(|e| format!("{label}: the surface of frame {im}: {e}"))
                };
                let backdrop = SurfaceOptions { fill_holes_px: BACKDROP_FILL_PX, ..SurfaceOptions::default() };
                Ok((im, (surface(&SurfaceOptions::default())?, surface(&backdrop)?)))
            })
            .collect::<Result<_, String>>()?;
        Ok(Self(built))
    }

    /// Frame `im` of the twin, rendered from frame `source`'s surface at the calibrated motion
    /// between them, over frame `im`'s own backdrop, its noise drawn for `draw`; depth readings
    /// only where the real frame `real` (frame `im`) has them; its mask every pixel.
    ///
    /// # Errors
    /// A message naming the frames.
    pub fn render(
        &self,
        seq: &PosedFrames,
        (source, im): (u32, u32),
        real: &RgbdFrame,
        opts: &TwinOptions,
        draw: u32,
    ) -> Result<RgbdFrame, String> {
        let surfaces = |i: u32| self.0.get(&i).ok_or_else(|| format!("no surface of frame {i}"));
        let motion = seq.calibrated_motion(source, im)?;
        let backdrop = (&surfaces(im)?.1, Pose::identity());
        let view = render_surface_view(&surfaces(source)?.0, Some(backdrop), &real.sensor, &motion, opts, draw)
            .map_err(|e| format!("the twin of frame {im} from frame {source}: {e}"))?;
        let mut depth = view.depth;
        // The real frame's holes (dark texture, grazing surfaces, shadows) are the sensor's, seen
        // from where it stood.
        for (d, r) in depth.as_mut_slice().iter_mut().zip(real.depth.as_slice()) {
            if *r == 0 {
                *d = 0;
            }
        }
        let (w, h) = (view.color.width() as usize, view.color.height() as usize);
        Ok(RgbdFrame {
            label: format!("{}/twin-{source:06}-{im:06}", real.label),
            color: view.color,
            depth,
            mask: Mask::filled(w, h, true),
            sensor: real.sensor,
        })
    }
}

/// The twin frames `(source, im)` a run needs: frame `im` rendered from frame `source`'s
/// surface ([`Surfaces::render`]); `whole` holds the real frames.
///
/// # Errors
/// A message naming the sequence and frame whose surface or view cannot be made.
pub fn render_twin_frames(
    seq: &PosedFrames,
    whole: &BTreeMap<u32, RgbdFrame>,
    wanted: &BTreeSet<(u32, u32)>,
    label: &str,
    opts: &TwinOptions,
) -> Result<BTreeMap<(u32, u32), RgbdFrame>, String> {
    let surfaces = Surfaces::of(whole, &wanted.iter().flat_map(|&(s, i)| [s, i]).collect(), label)?;
    wanted
        .par_iter()
        .map(|&(source, im)| {
            let real = whole.get(&im).ok_or_else(|| format!("{label}: frame {im} could not be read"))?;
            let frame = surfaces
                .render(seq, (source, im), real, opts, source * 1000 + im)
                .map_err(|e| format!("{label}: {e}"))?;
            Ok(((source, im), frame))
        })
        .collect()
}

/// Measures of how a twin's frames compare with the real ones: the numbers the SR300 shelf
/// profile is fitted to.
#[cfg(test)]
pub mod measure {
    use flowfilter_pipeline::RgbdFrame;
    use nalgebra::{Matrix3, Vector3};

    /// Mean |second difference| of three neighbouring depth readings along a row, in raw units
    /// (readings of one surface: the outer two within 10 units of each other).
    pub fn depth_roughness(frame: &RgbdFrame) -> f64 {
        let d = &frame.depth;
        let (w, h) = d.dims();
        let (mut sum, mut n) = (0.0, 0.0);
        for y in 0..h {
            for x in 1..w - 1 {
                let [a, b, c] = [x - 1, x, x + 1].map(|i| f64::from(*d.at(i, y)));
                if a > 0.0 && b > 0.0 && c > 0.0 && (a - c).abs() < 10.0 {
                    sum += (a - 2.0 * b + c).abs();
                    n += 1.0;
                }
            }
        }
        sum / n
    }

    /// Median |Laplacian| of the green channel (the finest texture and the noise).
    pub fn color_laplacian(frame: &RgbdFrame) -> f64 {
        let img = &frame.color;
        let g = |x: u32, y: u32| f64::from(img.get_pixel(x, y).0[1]);
        let mut v: Vec<f64> = (1..img.height() - 1)
            .flat_map(|y| (1..img.width() - 1).map(move |x| (x, y)))
            .map(|(x, y)| (4.0 * g(x, y) - g(x - 1, y) - g(x + 1, y) - g(x, y - 1) - g(x, y + 1)).abs())
            .collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    }

    /// Side of the windows whose tilt is measured, depth pixels (10 cm at 0.5 m).
    const WINDOW_PX: usize = 96;

    /// How two depth images of one view tilt against each other: their difference at readings
    /// away from depth edges (and within 1 cm), a rigid motion's part removed
    /// (`dz = wx y - wy x + tz` over the whole image), then a plane fitted in each window of [`WINDOW_PX`] (half
    /// overlapping, at least a third read): the median of the planes' tilts, degrees.
    pub fn median_window_tilt(a: &RgbdFrame, b: &RgbdFrame) -> f64 {
        let k = a.sensor.depth.intrinsics;
        let (w, h) = a.depth.dims();
        let at = |d: &flowfilter_pipeline::RawDepth, x: usize, y: usize| *d.at(x, y);
        let smooth = |x: usize, y: usize| {
            x >= 3 && y >= 3 && x + 3 < w && y + 3 < h && {
                let pairs = [((x + 3, y), (x - 3, y)), ((x, y + 3), (x, y - 3))];
                pairs.iter().all(|&(p, q)| {
                    let (u, v) = (at(&a.depth, p.0, p.1), at(&a.depth, q.0, q.1));
                    u > 0 && v > 0 && u.abs_diff(v) < 8
                })
            }
        };
        let mut points = vec![];
        for y in 0..h {
            for x in 0..w {
                let (za, zb) = (at(&a.depth, x, y), at(&b.depth, x, y));
                if za == 0 || zb == 0 || !smooth(x, y) {
                    continue;
                }
                let z = f64::from(za) * a.sensor.metres_per_unit;
                let r = (f64::from(zb) - f64::from(za)) * a.sensor.metres_per_unit;
                if r.abs() < 0.01 {
                    points.push((x, y, (x as f64 - k.cx) / k.fx * z, (y as f64 - k.cy) / k.fy * z, r));
                }
            }
        }
        let fit = |rows: &mut dyn Iterator<Item = (Vector3<f64>, f64)>| {
            let (mut m, mut v) = (Matrix3::<f64>::zeros(), Vector3::<f64>::zeros());
            for (j, r) in rows {
                m += j * j.transpose();
                v += j * r;
            }
            m.try_inverse().map(|i| i * v)
        };
        let Some(g) = fit(&mut points.iter().map(|&(_, _, px, py, r)| (Vector3::new(py, -px, 1.0), r))) else {
            return f64::NAN;
        };
        let mut tilts = vec![];
        for wy in (0..h - WINDOW_PX).step_by(WINDOW_PX / 2) {
            for wx in (0..w - WINDOW_PX).step_by(WINDOW_PX / 2) {
                let inside: Vec<_> = points
                    .iter()
                    .filter(|p| (wx..wx + WINDOW_PX).contains(&p.0) && (wy..wy + WINDOW_PX).contains(&p.1))
                    .map(|&(_, _, px, py, r)| (Vector3::new(1.0, px, py), r - (g[0] * py - g[1] * px + g[2])))
                    .collect();
                if inside.len() < WINDOW_PX * WINDOW_PX / 3 {
                    continue;
                }
                if let Some(c) = fit(&mut inside.into_iter()) {
                    tilts.push(c[1].hypot(c[2]).atan().to_degrees());
                }
            }
        }
        tilts.sort_by(f64::total_cmp);
        if tilts.is_empty() { f64::NAN } else { tilts[tilts.len() / 2] }
    }
}

#[cfg(test)]
mod tests {
    use super::measure::*;
    use super::*;

    fn shelf(name: &str) -> Option<std::path::PathBuf> {
        let dir = crate::in_repo(std::path::Path::new("../shared/data/realsense-shelf")).join(name);
        if dir.is_dir() {
            Some(dir)
        } else {
            eprintln!("skipped: {} is absent (the shared real sequences)", dir.display());
            None
        }
    }

    /// The SR300 shelf profile reproduces what it was fitted to, on frames of a shelf it was
    /// fitted on (shelf-A) and one it was not (shelf-J): a twin seen from its own frame's pose
    /// has the real frame's depth roughness within 20% and its fine texture within a grey level,
    /// and over the first eight pairs the twins of a target frame drawn twice tilt against each
    /// other as the real target frame tilts against a twin without the warp (the medians within
    /// 1.5x; two draws without the warp tilt by under 0.1 deg).
    #[test]
    fn the_shelf_twins_noise_matches_the_real_frames() {
        for name in ["shelf-A", "shelf-J"] {
            let Some(dir) = shelf(name) else { return };
            let seq = PosedFrames::open(&dir).unwrap();
            let ims: BTreeSet<u32> = (0..9).collect();
            let whole: BTreeMap<u32, RgbdFrame> = ims.iter().map(|&im| (im, seq.frame(im).unwrap())).collect();
            let surfaces = Surfaces::of(&whole, &ims, name).unwrap();
            let opts = twin_options(0, Some(NoiseProfile::sr300_shelf()));
            let own = surfaces.render(&seq, (2, 2), &whole[&2], &opts, 1).unwrap();
            let (real_rough, twin_rough) = (depth_roughness(&whole[&2]), depth_roughness(&own));
            assert!(
                (twin_rough / real_rough - 1.0).abs() < 0.2,
                "{name}: depth roughness {twin_rough:.2} against {real_rough:.2}"
            );
            let (real_lap, twin_lap) = (color_laplacian(&whole[&2]), color_laplacian(&own));
            assert!((twin_lap - real_lap).abs() <= 1.0, "{name}: colour Laplacian {twin_lap} against {real_lap}");

            let mut flat = opts.clone();
            flat.noise.as_mut().unwrap().depth.warp_sigma_m = 0.0;
            let twin = |(a, b): (u32, u32), o: &TwinOptions, draw: u32| {
                surfaces.render(&seq, (a, b), &whole[&b], o, draw).unwrap()
            };
            let floor = median_window_tilt(&twin((2, 3), &flat, 2), &twin((2, 3), &flat, 5));
            assert!(floor < 0.1, "{name}: two unwarped draws tilt by {floor:.2} deg");
            let (mut real_tilts, mut twin_tilts): (Vec<f64>, Vec<f64>) = (0..8)
                .into_par_iter()
                .map(|a| {
                    let real = median_window_tilt(&twin((a, a + 1), &flat, 2), &whole[&(a + 1)]);
                    (
                        real,
                        median_window_tilt(&twin((a, a + 1), &opts, 10 * a + 3), &twin((a, a + 1), &opts, 10 * a + 4)),
                    )
                })
                .unzip();
            let median = |v: &mut Vec<f64>| {
                v.sort_by(f64::total_cmp);
                (v[3] + v[4]) / 2.0
            };
            let ratio = median(&mut twin_tilts) / median(&mut real_tilts);
            assert!(
                (1.0 / 1.5..1.5).contains(&ratio),
                "{name}: windows tilt by {twin_tilts:.2?} deg between twins, {real_tilts:.2?} deg against the real frames"
            );
        }
    }
}
