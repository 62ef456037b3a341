//! Sensor noise profiles (TOML) and their application to rendered depth and colour.

use crate::error::SynthError;
use flowfilter_geometry::{DepthMap, Mask};
use image::RgbImage;
use rand::Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Structured-light depth noise parameters (see `profiles/carmine.toml` for sources).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthNoise {
    /// Projector-camera baseline, metres.
    pub baseline_m: f64,
    /// Disparity steps per pixel (8 = 1/8 px quantisation); 0 disables quantisation.
    pub disparity_subpixel: f64,
    /// Axial noise `sigma(z) = a + b (z - z0)^2`: `a`, metres.
    pub axial_sigma_a_m: f64,
    /// `b`, metres per square metre.
    pub axial_sigma_b_m: f64,
    /// `z0`, metres.
    pub axial_sigma_z0_m: f64,
    /// Angle (between surface normal and viewing ray) where depth starts to drop out.
    pub grazing_start_deg: f64,
    /// Angle beyond which depth is always missing.
    pub grazing_full_deg: f64,
    /// Whether points hidden from the projector lose their depth.
    pub projector_shadows: bool,
    /// Depth margin of the projector visibility test, metres.
    pub shadow_tolerance_m: f64,
    /// Neighbour depth difference that makes a pixel an edge pixel, metres.
    pub edge_threshold_m: f64,
    /// Probability that an edge pixel becomes a flying pixel.
    pub flying_probability: f64,
    /// Probability that an edge pixel takes its neighbour's depth.
    pub lateral_jitter_probability: f64,
    /// RMS of a smooth depth error field drawn afresh for every view, metres (0 = none): the
    /// view-dependent warp of a real sensor's depth, which tilts a small patch differently
    /// from one view to the next.
    #[serde(default)]
    pub warp_sigma_m: f64,
    /// Typical wavelength of that field on the depth image, pixels.
    #[serde(default = "default_warp_wavelength_px")]
    pub warp_wavelength_px: f64,
}

fn default_warp_wavelength_px() -> f64 {
    200.0
}

/// Plane waves summed into a view's depth warp field.
const WARP_WAVES: usize = 8;

/// A smooth random field of RMS `sigma` (metres) over pixels: [`WARP_WAVES`] plane waves of
/// random directions, phases and wavelengths within 0.7-1.4 times `wavelength_px`.
struct WarpField {
    waves: Vec<(f64, f64, f64)>,
    amplitude: f64,
}

impl WarpField {
    fn draw(sigma: f64, wavelength_px: f64, rng: &mut impl Rng) -> Self {
        let waves = (0..WARP_WAVES)
            .map(|_| {
                let (angle, phase) =
                    (rng.random_range(0.0..std::f64::consts::TAU), rng.random_range(0.0..std::f64::consts::TAU));
                let k = std::f64::consts::TAU / (wavelength_px * rng.random_range(0.7..1.4));
                (k * angle.cos(), k * angle.sin(), phase)
            })
            .collect();
        Self { waves, amplitude: sigma * (2.0 / WARP_WAVES as f64).sqrt() }
    }

    fn at(&self, x: f64, y: f64) -> f64 {
        self.amplitude * self.waves.iter().map(|&(kx, ky, phase)| (kx * x + ky * y + phase).cos()).sum::<f64>()
    }
}

/// Colour noise parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColorNoise {
    /// Gaussian read noise, 8-bit levels.
    pub noise_sigma: f64,
    /// Gaussian blur sigma, pixels (0 = none).
    pub blur_sigma_px: f64,
    /// JPEG quality of stored images, 1-100.
    pub jpeg_quality: u8,
}

/// A complete sensor noise profile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseProfile {
    /// Profile name.
    pub name: String,
    /// Depth noise.
    pub depth: DepthNoise,
    /// Colour noise.
    pub color: ColorNoise,
}

/// The built-in Carmine / Kinect v1 profile.
pub const CARMINE_TOML: &str = include_str!("../profiles/carmine.toml");

/// The profile fitted to the real YCB-Video sample (an Xtion at 640 x 480; see the file).
pub const XTION_SAMPLE_TOML: &str = include_str!("../profiles/xtion-sample.toml");

/// The profile of the twins of the real RealSense SR300 shelf sequences (see the file).
pub const SR300_SHELF_TOML: &str = include_str!("../profiles/sr300-shelf.toml");

impl NoiseProfile {
    /// Parse and validate a TOML profile; `source_name` is used in error messages.
    pub fn from_toml(text: &str, source_name: &str) -> Result<Self, SynthError> {
        let err = |message: String| SynthError::NoiseProfile { source_name: source_name.into(), message };
        let table: toml::Table = toml::from_str(text).map_err(|e| err(e.to_string()))?;
        flowfilter_geometry::params::reject_non_finite(&table).map_err(|e| err(e.to_string()))?;
        let p: NoiseProfile = toml::from_str(text).map_err(|e| err(e.to_string()))?;
        let d = &p.depth;
        let checks = [
            (d.baseline_m > 0.0, "depth.baseline_m must be > 0"),
            (d.disparity_subpixel >= 0.0, "depth.disparity_subpixel must be >= 0"),
            (d.axial_sigma_a_m >= 0.0 && d.axial_sigma_b_m >= 0.0, "depth.axial_sigma_* must be >= 0"),
            (d.grazing_start_deg <= d.grazing_full_deg, "depth.grazing_start_deg must be <= grazing_full_deg"),
            ((0.0..=1.0).contains(&d.flying_probability), "depth.flying_probability must be in [0, 1]"),
            ((0.0..=1.0).contains(&d.lateral_jitter_probability), "depth.lateral_jitter_probability must be in [0, 1]"),
            (
                d.flying_probability + d.lateral_jitter_probability <= 1.0,
                "flying + lateral jitter probabilities exceed 1",
            ),
            (p.color.noise_sigma >= 0.0 && p.color.blur_sigma_px >= 0.0, "color sigmas must be >= 0"),
            (d.warp_sigma_m >= 0.0, "depth.warp_sigma_m must be >= 0"),
            (d.warp_wavelength_px > 0.0, "depth.warp_wavelength_px must be > 0"),
            ((1..=100).contains(&p.color.jpeg_quality), "color.jpeg_quality must be in 1..=100"),
        ];
        match checks.iter().find(|(ok, _)| !ok) {
            Some((_, msg)) => Err(err((*msg).into())),
            None => Ok(p),
        }
    }

    /// The built-in Carmine profile.
    pub fn carmine() -> Self {
        Self::from_toml(CARMINE_TOML, "carmine (built in)").expect("built-in profile is valid")
    }

    /// The built-in profile fitted to the real YCB-Video sample (`profiles/xtion-sample.toml`).
    pub fn xtion_sample() -> Self {
        Self::from_toml(XTION_SAMPLE_TOML, "xtion-sample (built in)").expect("built-in profile is valid")
    }

    /// The built-in profile of the twins of the real SR300 shelf sequences
    /// (`profiles/sr300-shelf.toml`).
    pub fn sr300_shelf() -> Self {
        Self::from_toml(SR300_SHELF_TOML, "sr300-shelf (built in)").expect("built-in profile is valid")
    }

    /// `none` -> no noise; `carmine`, `xtion-sample` and `sr300-shelf` -> the built-in profiles;
    /// anything else is a TOML file path.
    pub fn resolve(spec: &str) -> Result<Option<Self>, SynthError> {
        match spec {
            "none" => Ok(None),
            "carmine" => Ok(Some(Self::carmine())),
            "xtion-sample" => Ok(Some(Self::xtion_sample())),
            "sr300-shelf" => Ok(Some(Self::sr300_shelf())),
            path => {
                let text = std::fs::read_to_string(Path::new(path)).map_err(|e| SynthError::NoiseProfile {
                    source_name: path.into(),
                    message: format!(
                        "cannot read ({e}); use 'none', 'carmine', 'xtion-sample', 'sr300-shelf' or a TOML file"
                    ),
                })?;
                Self::from_toml(&text, path).map(Some)
            }
        }
    }
}

impl DepthNoise {
    /// Axial standard deviation at depth `z`.
    pub fn axial_sigma(&self, z: f64) -> f64 {
        self.axial_sigma_a_m + self.axial_sigma_b_m * (z - self.axial_sigma_z0_m).powi(2)
    }

    /// Depth step of the disparity quantisation at depth `z` for focal length `f` (pixels).
    pub fn quantisation_step(&self, z: f64, f: f64) -> f64 {
        if self.disparity_subpixel <= 0.0 { 0.0 } else { z * z / (f * self.baseline_m * self.disparity_subpixel) }
    }

    /// Quantise a depth through disparity.
    pub fn quantise(&self, z: f64, f: f64) -> f64 {
        if self.disparity_subpixel <= 0.0 {
            return z;
        }
        let fb = f * self.baseline_m;
        let d = (fb / z * self.disparity_subpixel).round() / self.disparity_subpixel;
        if d > 0.0 { fb / d } else { 0.0 }
    }
}

/// Per-pixel inputs of the depth noise model on the depth camera grid.
pub struct DepthNoiseInput<'a> {
    /// Noise-free depth (metres, 0 = no surface).
    pub clean: &'a DepthMap,
    /// `|cos|` of the angle between the surface normal and the viewing ray.
    pub cos_incidence: &'a [f32],
    /// Whether the projector cannot see the point.
    pub shadowed: &'a [bool],
    /// Focal length of the depth camera (pixels), for disparity.
    pub focal_px: f64,
}

/// Which pixels the noise model made special, for evaluating edge filters.
#[derive(Debug, Clone)]
pub struct DepthNoiseTruth {
    /// Flying pixels: depth between two surfaces at a discontinuity.
    pub flying: Mask,
    /// Edge pixels that took their neighbour's (valid) depth.
    pub jittered: Mask,
    /// Pixels with a surface but no reading (grazing angle or projector shadow).
    pub dropped: Mask,
}

/// Depth assumed for a neighbour that has no surface, relative to the pixel (metres).
const NO_SURFACE_BEHIND_M: f64 = 0.5;

/// Apply the structured-light model to a clean depth map. Deterministic given `rng`.
pub fn apply_depth_noise(p: &DepthNoise, input: &DepthNoiseInput, rng: &mut impl Rng) -> (DepthMap, DepthNoiseTruth) {
    let (w, h) = input.clean.dims();
    let clean = input.clean.as_slice();
    let mut out = vec![0.0f32; w * h];
    let mut flying = vec![false; w * h];
    let mut jittered = vec![false; w * h];
    let mut dropped = vec![false; w * h];
    let (cos_start, cos_full) = (p.grazing_start_deg.to_radians().cos(), p.grazing_full_deg.to_radians().cos());
    let unit = Normal::new(0.0, 1.0).expect("valid normal");
    // Drawn only when asked for, so that the other profiles' noise streams stay as they were.
    let warp = (p.warp_sigma_m > 0.0).then(|| WarpField::draw(p.warp_sigma_m, p.warp_wavelength_px, rng));
    for y in 0..h {
        for x in 0..w {
            let k = y * w + x;
            let z = f64::from(clean[k]);
            // Draw every random number for every pixel so that the stream does not depend on
            // the scene: the same seed gives the same noise field.
            let (u_drop, u_edge, u_mix, gauss) =
                (rng.random::<f64>(), rng.random::<f64>(), rng.random::<f64>(), unit.sample(rng));
            if z <= 0.0 {
                continue;
            }
            let c = f64::from(input.cos_incidence[k]);
            let p_drop = if c <= cos_full {
                1.0
            } else if c >= cos_start {
                0.0
            } else {
                (cos_start - c) / (cos_start - cos_full)
            };
            if u_drop < p_drop || (p.projector_shadows && input.shadowed[k]) {
                dropped[k] = true;
                continue;
            }
            // The neighbour across the largest discontinuity (a missing neighbour counts as far).
            let mut edge: Option<f64> = None;
            for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
                let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                    continue;
                }
                // A neighbour with no surface (out of range) counts as half a metre behind.
                let zn = match f64::from(clean[ny as usize * w + nx as usize]) {
                    zn if zn > 0.0 => zn,
                    _ => z + NO_SURFACE_BEHIND_M,
                };
                if (zn - z).abs() > p.edge_threshold_m && edge.is_none_or(|e| (zn - z).abs() > (e - z).abs()) {
                    edge = Some(zn);
                }
            }
            let mut zz = z;
            if let Some(zn) = edge {
                if u_edge < p.flying_probability {
                    zz = z + (0.2 + 0.6 * u_mix) * (zn - z);
                    flying[k] = true;
                } else if u_edge < p.flying_probability + p.lateral_jitter_probability {
                    zz = zn;
                    jittered[k] = true;
                }
            }
            zz += gauss * p.axial_sigma(zz);
            if let Some(warp) = &warp {
                zz += warp.at(x as f64, y as f64);
            }
            out[k] = p.quantise(zz, input.focal_px) as f32;
        }
    }
    let mask = |v: Vec<bool>| Mask::from_vec(w, h, v).expect("sized");
    (
        DepthMap::from_vec(w, h, out).expect("sized"),
        DepthNoiseTruth { flying: mask(flying), jittered: mask(jittered), dropped: mask(dropped) },
    )
}

/// Separable Gaussian blur of an RGB image (edges clamped).
pub fn gaussian_blur(img: &RgbImage, sigma: f64) -> RgbImage {
    if sigma <= 0.0 {
        return img.clone();
    }
    let r = (3.0 * sigma).ceil() as i64;
    let kernel: Vec<f32> = (-r..=r).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32).collect();
    let norm: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / norm).collect();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let src: Vec<[f32; 3]> = img.pixels().map(|p| p.0.map(f32::from)).collect();
    let pass = |src: &[[f32; 3]], horizontal: bool| -> Vec<[f32; 3]> {
        let mut dst = vec![[0.0f32; 3]; w * h];
        dst.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, out) in row.iter_mut().enumerate() {
                let mut acc = [0.0f32; 3];
                for (i, kv) in kernel.iter().enumerate() {
                    let o = i as i64 - r;
                    let (sx, sy) = if horizontal {
                        ((x as i64 + o).clamp(0, w as i64 - 1) as usize, y)
                    } else {
                        (x, (y as i64 + o).clamp(0, h as i64 - 1) as usize)
                    };
                    let s = src[sy * w + sx];
                    for c in 0..3 {
                        acc[c] += kv * s[c];
                    }
                }
                *out = acc;
            }
        });
        dst
    };
    let blurred = pass(&pass(&src, true), false);
    RgbImage::from_fn(img.width(), img.height(), |x, y| {
        image::Rgb(blurred[y as usize * w + x as usize].map(|v| v.round().clamp(0.0, 255.0) as u8))
    })
}

/// Add Gaussian read noise (8-bit levels) to every channel.
pub fn add_color_noise(img: &mut RgbImage, sigma: f64, rng: &mut impl Rng) {
    if sigma <= 0.0 {
        return;
    }
    let n = Normal::new(0.0, sigma).expect("valid sigma");
    for v in img.iter_mut() {
        *v = (f64::from(*v) + n.sample(rng)).round().clamp(0.0, 255.0) as u8;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_profile_parses_and_bad_profiles_are_rejected() {
        let p = NoiseProfile::carmine();
        assert_eq!(p.name, "carmine");
        assert!((p.depth.axial_sigma(0.4) - 0.0012).abs() < 1e-12);
        let bad = CARMINE_TOML.replace("jpeg_quality = 90", "jpeg_quality = 0");
        let e = NoiseProfile::from_toml(&bad, "x.toml").unwrap_err().to_string();
        assert!(e.contains("x.toml") && e.contains("jpeg_quality"), "{e}");
        let unknown = CARMINE_TOML.replace("baseline_m", "baseline_mm");
        let e = NoiseProfile::from_toml(&unknown, "y.toml").unwrap_err().to_string();
        assert!(e.contains("baseline_mm"), "{e}");
        assert!(NoiseProfile::resolve("none").unwrap().is_none());
        assert!(NoiseProfile::resolve("/no/such/profile.toml").is_err());
    }

    #[test]
    fn quantisation_step_matches_disparity_model() {
        let p = NoiseProfile::carmine().depth;
        let f = 575.0;
        let step = p.quantisation_step(0.8, f);
        // Two adjacent disparity levels are one step apart.
        let fb = f * p.baseline_m;
        let d = (fb / 0.8 * 8.0).round() / 8.0;
        let gap = fb / (d - 0.125) - fb / d;
        assert!((gap - step).abs() / step < 0.01, "{gap} vs {step}");
        assert!((p.quantise(0.8, f) - 0.8).abs() <= step / 2.0 + 1e-12);
    }

    /// The view's depth warp is smooth and of the profile's RMS (one draw over a 640 x 480 image
    /// of 200-px waves: within 40%), a new draw gives a new field, and a profile without it
    /// (the keys absent) draws the same noise as before it existed.
    #[test]
    fn the_depth_warp_is_a_smooth_field_of_the_profiles_size() {
        use rand::SeedableRng;
        let (w, h) = (640, 480);
        let clean = DepthMap::from_vec(w, h, vec![0.8; w * h]).unwrap();
        let (cos, shadowed) = (vec![1.0f32; w * h], vec![false; w * h]);
        let input = DepthNoiseInput { clean: &clean, cos_incidence: &cos, shadowed: &shadowed, focal_px: 477.0 };
        let mut p = NoiseProfile::sr300_shelf().depth;
        p.axial_sigma_a_m = 0.0;
        let field = |p: &DepthNoise, seed: u64| {
            let (d, _) = apply_depth_noise(p, &input, &mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
            d.as_slice().iter().map(|&z| f64::from(z) - 0.8).collect::<Vec<f64>>()
        };
        let a = field(&p, 1);
        let rms = (a.iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt();
        assert!((rms / p.warp_sigma_m - 1.0).abs() < 0.4, "RMS {rms} against {}", p.warp_sigma_m);
        let step =
            (0..h).flat_map(|y| (1..w).map(move |x| (x, y))).map(|(x, y)| (a[y * w + x] - a[y * w + x - 1]).abs());
        assert!(step.fold(0.0, f64::max) < p.warp_sigma_m / 4.0, "neighbours differ by more than a quarter of the RMS");
        let b = field(&p, 2);
        assert!(a.iter().zip(&b).any(|(u, v)| (u - v).abs() > p.warp_sigma_m / 2.0), "a new draw, a new field");
        let carmine = NoiseProfile::carmine().depth;
        assert_eq!(carmine.warp_sigma_m, 0.0);
        let with_keys = NoiseProfile::from_toml(
            &CARMINE_TOML.replace(
                "lateral_jitter_probability = 0.25",
                "lateral_jitter_probability = 0.25\nwarp_sigma_m = 0.0\nwarp_wavelength_px = 50.0",
            ),
            "carmine with the keys",
        )
        .unwrap()
        .depth;
        assert_eq!(field(&carmine, 3), field(&with_keys, 3));
    }
}
